"""``python -m staggered_cli``: the same as the ``staggered`` command."""

from staggered_cli.cli.main import main

if __name__ == "__main__":
    main()
