"""`python -m pbc.main [overrides]`: the README's main job; the command lives on the entry floor,
pbc/cli/main_job.py (also `pbc main`)."""

if __name__ == "__main__":  # `python -m pbc.main`, the README's command: the entry floor runs it
    from pbc.cli import run_as_module

    run_as_module("main")
