"""`python -m pbc.train +experiment=NAME [overrides]`: train one model, test it, write metrics.json.
The command lives on the entry floor, pbc/cli/train.py (also `pbc train`); the job is pbc.jobs.train."""

if __name__ == "__main__":  # `python -m pbc.train`, the users' own command: the entry floor runs it
    from pbc.cli import run_as_module

    run_as_module("train")
