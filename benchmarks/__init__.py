"""evo-door's benchmarks: ``python -m benchmarks`` runs them as one suite
(:mod:`benchmarks.suite`); each ``bench_*.py`` still runs on its own."""
