"""Nothing lost and nothing random: atomic outputs survive an interrupted run, and runs with the
same seed give the same numbers."""

import json

import pytest
from helpers_dataset import synthetic_dataset

from relcal.calibration.kinds import poses
from relcal.cli import main
from relcal.io import File, Folder, write_set, write_text


def test_a_write_interrupted_while_staging_keeps_the_old_files(tmp_path):
    path = tmp_path / "model.yaml"
    write_text(path, "old\n")

    def half_written(folder):
        (folder / "big.bin").write_bytes(b"half of the new")
        raise KeyboardInterrupt

    new = Folder(tmp_path / "set", {"a.txt": "new"}, fill=half_written)
    with pytest.raises(KeyboardInterrupt):
        write_set(File(path, "new\n"), new)
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["model.yaml"]  # no temporary left behind


def test_interrupted_calibration_leaves_earlier_outputs_intact(tmp_path, monkeypatch, capsys):
    syn = synthetic_dataset(tmp_path / "d", n=20)
    out = tmp_path / "out"
    assert main(["calibrate", str(syn.root), "--out", str(out), "--quiet"]) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(poses, "held_out", interrupted)
    assert main(["calibrate", str(syn.root), "--out", str(out), "--quiet", "--seed", "3"]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def _without_timing(doc):
    if isinstance(doc, dict):
        return {k: _without_timing(v) for k, v in doc.items() if k not in ("seconds", "run_id")}
    if isinstance(doc, list):
        return [_without_timing(v) for v in doc]
    return doc


def test_same_seed_same_numbers(tmp_path):
    for k in range(2):
        assert (
            main(
                [
                    "simulate",
                    "--poses",
                    "15",
                    "--seed",
                    "7",
                    "--quiet",
                    "--noise",
                    "0.05,0.01",
                    "--json",
                    str(tmp_path / f"s{k}.json"),
                ]
            )
            == 0
        )
    a, b = (json.loads((tmp_path / f"s{k}.json").read_text()) for k in range(2))
    assert _without_timing(a) == _without_timing(b)
    syn = synthetic_dataset(tmp_path / "d", n=20)
    for k in range(2):
        assert main(["calibrate", str(syn.root), "--out", str(tmp_path / f"o{k}"), "--quiet"]) == 0
    a, b = (json.loads((tmp_path / f"o{k}/results.json").read_text()) for k in range(2))
    assert _without_timing(a) == _without_timing(b)


def test_outputs_get_the_usual_file_mode(tmp_path):
    import os

    path = tmp_path / "results.json"
    write_text(path, "{}\n")
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask
