"""evo-door: a workbench for re-engineering how a product feels.

Physical and haptic models of a dishwasher door, compiled fixed-step integrators,
genetic-algorithm parameter estimation from measured trials and translation of a
chosen haptic feel back into technical specifications.
"""

__version__ = "0.2.0.dev0"
