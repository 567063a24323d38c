"""`python -m pbc.sweeps NAME [overrides]`: a named sweep end to end: data, multirun, evaluation, report.
The command lives on the entry floor, pbc/cli/sweeps.py (also `pbc sweeps`); the job is pbc.jobs.sweeps."""

if __name__ == "__main__":  # `python -m pbc.sweeps`: the entry floor runs it
    from pbc.cli import run_as_module

    run_as_module("sweeps")
