"""`python -m pbc.report SWEEP_DIR [--out DIR]`: the report (tables, figures) of a sweep dir.
The command lives on the entry floor, pbc/cli/report.py (also `pbc report`); the job is pbc.jobs.report."""

if __name__ == "__main__":  # `python -m pbc.report`: the entry floor runs it
    from pbc.cli import run_as_module

    run_as_module("report")
