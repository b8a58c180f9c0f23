"""Sub-commands beyond ``run`` and ``compare``, one module each.

Each module in :data:`COMMANDS` defines ``register(subparsers)``, which adds its
sub-parser and sets ``func`` to a function ``(args) -> int`` (exit status).
Those functions raise :class:`~graphslam.errors.GraphSlamError` for bad input;
``graphslam.cli.main`` turns it into one line. Modules are imported only when
the parser is built, so nothing runs at import time.
"""

#: Module names (under ``graphslam.commands``) registered by the CLI, in help order.
COMMANDS: tuple[str, ...] = ("vocab", "loops")
