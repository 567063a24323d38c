"""`python -m pbc.generate data=tshirt_small [preview=true]`: the command lives on the entry floor,
pbc/cli/generate.py (also `pbc generate`); the dataset is made by pbc.data.generate."""

if __name__ == "__main__":  # `python -m pbc.generate`, the users' own command: the entry floor runs it
    from pbc.cli import run_as_module

    run_as_module("generate")
