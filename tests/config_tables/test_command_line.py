"""config_tables.command_line: a usage error is one line on stderr and exit status 2."""
from __future__ import annotations

import pytest

from config_tables.command_line import USAGE_ERROR, OneLineParser


def test_usage_error_is_one_line_and_exit_2(capsys):
    parser = OneLineParser(prog="tool")
    parser.add_argument("--count", type=int, required=True)
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args(["--count", "many"])
    assert exit_info.value.code == USAGE_ERROR == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tool: error: ") and "'many'" in err
    assert parser.parse_args(["--count", "3"]).count == 3
