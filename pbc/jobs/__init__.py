"""The commands' jobs, one module each (the commands themselves live in ``pbc.cli``): train, evaluate,
predict, edit, view, sweeps, report, the wrong-body study (``robustness``), ``garment_fit`` and the writers
they share."""
