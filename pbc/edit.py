"""`python -m pbc.edit RUN_OR_DATA [options]`: edit a cloth image -> a new 3D garment (appendix B).
The command lives on the entry floor, pbc/cli/edit.py (also `pbc edit`); the job is pbc.jobs.edit."""

if __name__ == "__main__":  # `python -m pbc.edit`, the users' own command: the entry floor runs it
    from pbc.cli import run_as_module

    run_as_module("edit")
