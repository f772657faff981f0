"""The CLI as a test calls it: fgen(capsys, *args) -> (exit code, stdout, stderr)."""
from __future__ import annotations

import pytest

from fgcli.cli import main


def fgen(capsys, *args):
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in args])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err
    return e.value.code, cap.out, cap.err
