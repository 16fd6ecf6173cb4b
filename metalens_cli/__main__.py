"""`python -m metalens_cli` runs the command-line app."""

from metalens_cli.cli.main import cli

if __name__ == "__main__":
    cli()
