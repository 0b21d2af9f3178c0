"""`mogo serve` on the command line: listed in the help, one line when the extra is missing,
one line for a bad flag, a warning before listening beyond this machine."""
import importlib.util

import pytest

from mogo.cli import main
from mogo.serve import cli as serve_cli


def test_serve_is_a_verb_of_mogo(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "serve" in capsys.readouterr().out


def test_without_the_extra_it_says_how_to_install_it(monkeypatch, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "aiohttp" else real(name, *a))
    assert main(["serve"]) == 2
    assert capsys.readouterr().err == ("mogo: error: this command needs the serve extra: "
                                       "pip install 'mogo-edge[serve]'\n")


@pytest.mark.parametrize("flags", [["--port", "70000"], ["--max-streams", "0"],
                                   ["--threads", "0"]])
def test_bad_flags_are_one_line(flags, capsys):
    pytest.importorskip("aiohttp")  # without the extra, the one line says to install it
    assert main(["serve", *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mogo: error: ") and err.count("\n") == 1


def test_only_loopback_addresses_count_as_local():
    assert all(serve_cli._is_local(h) for h in ("127.0.0.1", "::1", "localhost", "127.0.0.2"))
    assert not any(serve_cli._is_local(h) for h in ("0.0.0.0", "192.168.1.5", "example.org"))
