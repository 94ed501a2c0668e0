"""``zipon annotate`` refuses what it cannot serve with one line and exit 1 (serving itself is tested through the
app in test_api.py and test_browser.py)."""

from __future__ import annotations

import socket

from zipon.cli import main


def test_unknown_scene(shared_root, capsys):
    code = main(["-p", str(shared_root / "params.yaml"), "annotate", "nowhere", "--port", "1"])
    err = capsys.readouterr().err
    assert code == 1 and "unknown scene 'nowhere'; params scenes: ['tiny']" in " ".join(err.split())
    assert "Traceback" not in err


def test_a_port_in_use(shared_root, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code = main(["-p", str(shared_root / "params.yaml"), "annotate", "tiny", "--port", str(port)])
    err = " ".join(capsys.readouterr().err.split())
    assert code == 1 and f"--host 127.0.0.1 --port {port}: cannot listen there" in err and "pick another --port" in err


def test_usage_errors_exit_2(shared_root, capsys):
    assert main(["-p", str(shared_root / "params.yaml"), "annotate", "tiny", "--port", "0"]) == 2
    assert "--port" in capsys.readouterr().err
