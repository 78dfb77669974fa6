"""The ``pyethercat`` command line; entry point :func:`pyethercat.cli.main.main`."""

__all__: list[str] = []
