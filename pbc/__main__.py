"""`python -m pbc COMMAND [args]`: the dispatcher of the entry floor (pbc.cli)."""

from pbc.cli import main

main()
