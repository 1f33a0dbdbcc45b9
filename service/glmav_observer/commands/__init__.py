"""Subcommands of ``glmav-observer``; each module provides ``register(subparsers)``."""
