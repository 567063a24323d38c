"""`python -m pbc.evaluate whole_run=... patch_runs=...`: whole vs stitched patch models on a dataset split.
The command lives on the entry floor, pbc/cli/evaluate.py (also `pbc evaluate`); the job is pbc.jobs.evaluate."""

if __name__ == "__main__":  # `python -m pbc.evaluate`, the users' own command: the entry floor runs it
    from pbc.cli import run_as_module

    run_as_module("evaluate")
