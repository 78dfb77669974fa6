"""The package's version, in a module of its own: the parts that report it (the control
socket's hello, ``pyethercat version``) import it from here, not from the package root,
which loads the master on use."""

__all__ = ["__version__"]

__version__ = "0.1.0"
