"""The ground floor: files only. Where the shipped ``conf/`` and ``patches/`` are (``paths``), atomic writers
and named file errors (``io``), the Hydra config composed outside an entry point (``config``), the run record
(``runs``) and the input checks every door calls (``validate``)."""
