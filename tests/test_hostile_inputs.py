"""Hostile input to the importers, plan files, the fleet and the API: each case is refused with
exit 2 naming the file, line or option and the likely cause, with nothing written (or, where the
input is merely unusual, read right)."""

from __future__ import annotations

from pathlib import Path

import pytest

from relcal.cli import main


def refused(capsys, argv, *patterns) -> str:
    """Run ``argv``: exit 2, no traceback, every pattern in the message."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and "internal error" not in err, err
    for pattern in patterns:
        assert pattern in err, err
    return err


@pytest.mark.parametrize(
    ("name", "content", "expect"),
    [
        ("run.bag", b"not a bag at all\n", "not a bag rosbags can read"),
        ("run.mcap", b"", "not a bag rosbags can read"),
        ("run.mcap", b"\x89MCAP0\r\n" + bytes(range(256)) * 2, "not a bag rosbags can read"),
        ("run_bag", None, "a folder without a ROS 2 bag's metadata.yaml"),
    ],
)
def test_rosbag_that_is_not_a_bag(tmp_path, capsys, name, content, expect):
    pytest.importorskip("rosbags")
    bag = tmp_path / name
    if content is None:
        bag.mkdir()
    else:
        bag.write_bytes(content)
    out = tmp_path / "out"
    argv = ["import", "rosbag", bag, "--joints", "/j", "--pose", "/p", "--out", out]
    refused(capsys, argv, str(bag), expect, "expected a ROS 1 .bag")
    assert not out.exists()
