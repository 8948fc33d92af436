"""``python -m oacli`` entry point."""

from oacli.cli import main

if __name__ == "__main__":
    main()
