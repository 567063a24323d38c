"""`python -m pbc.predict RUN --poses test|FILE`: body poses -> garment meshes from trained runs.
The command lives on the entry floor, pbc/cli/predict.py (also `pbc predict`);
the job is pbc.jobs.predict (the predictor: pbc.inference)."""

if __name__ == "__main__":  # `python -m pbc.predict`, the users' own command: the entry floor runs it
    from pbc.cli import run_as_module

    run_as_module("predict")
