"""Running an entry-floor command in-process, as its script would: the exit status it ends with."""

from __future__ import annotations

import pytest


def exit_code(main, argv: list[str]) -> int:
    """`main(argv)` of a pbc.cli command (it always exits): its exit status, 0 for success."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    code = e.value.code
    return 0 if code is None else code if isinstance(code, int) else 1
