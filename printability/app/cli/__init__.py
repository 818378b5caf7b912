"""The ``printability`` command line: one module per subcommand, each a thin adapter."""

__all__: list[str] = []
