"""``python -m pyethercat`` runs the command line."""

from pyethercat.cli.main import main

if __name__ == "__main__":
    main()
