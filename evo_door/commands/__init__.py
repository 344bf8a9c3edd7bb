"""Sub-commands of ``evo-door``: one module each, with ``register(subparsers)``.

Shared argument helpers live in :mod:`._common`.
"""
