"""Hostile input to the importers, plan files, the fleet and the API: each case is refused with
exit 2 naming the file, line or option and the likely cause, with nothing written (or, where the
input is merely unusual, read right)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from conftest import DATA

from relcal.cli import main

MUKCA = DATA / "mukca"
POSITIONER = DATA / "rct_positioner" / "positioner_kinematic_measurements.yaml"


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


def positioner_file(path: Path, names: list[str]) -> Path:
    """The first observations of the real positioner file under other names (YAML keys)."""
    data = yaml.safe_load(POSITIONER.read_text())
    path.write_text(yaml.safe_dump(dict(zip(names, data.values(), strict=False))))
    return path


def test_positioner_without_observations(tmp_path, capsys):
    source = tmp_path / "m.yaml"
    source.write_text("{}\n")
    out = tmp_path / "out"
    refused(capsys, ["import", "rct-positioner", source, "--out", out], "0 observations")
    assert not out.exists()


@pytest.mark.parametrize(
    ("bad", "expect"),
    [(" ", "an empty name"), ("e\nf", "a line break inside the name 'e\\nf'"), ("a ", "one id")],
)
def test_positioner_ids_that_cannot_be_sample_ids(tmp_path, capsys, bad, expect):
    source = positioner_file(tmp_path / "m.yaml", ["a", "b", "c", bad])
    out = tmp_path / "out"
    refused(capsys, ["import", "rct-positioner", source, "--out", out], expect)
    assert not out.exists()


def test_positioner_ids_with_commas_and_quotes_read_back(tmp_path):
    from relcal import load_dataset

    names = ["a,b", 'c"d', "x y", "g\u202eh", "5"]
    source = positioner_file(tmp_path / "m.yaml", names)
    assert main(["import", "rct-positioner", str(source), "--out", str(tmp_path / "d")]) == 0
    assert sorted(load_dataset(tmp_path / "d").ids) == sorted(names)


def mukca_robot(tmp_path: Path, hole_0: str | bytes, name: str = "A") -> Path:
    """A robot folder of two placements (the real panda_1 front's sockets), placement ``name``'s
    hole_0.csv replaced by ``hole_0``."""
    root = tmp_path / "robot"
    for place in (name, "B"):
        (root / place).mkdir(parents=True)
        for hole in ("hole_0.csv", "hole_1.csv"):
            (root / place / hole).write_bytes((MUKCA / "data/panda_1/front" / hole).read_bytes())
    target = root / name / "hole_0.csv"
    (target.write_bytes if isinstance(hole_0, bytes) else target.write_text)(hole_0)
    return root


def front_rows() -> list[str]:
    return (MUKCA / "data/panda_1/front/hole_0.csv").read_text().splitlines()


def import_mukca(tmp_path, root) -> list:
    urdf = MUKCA / "urdf" / "panda.urdf"
    return ["import", "mukca", root, "--urdf", urdf, "--distance", "0.05", "--out", tmp_path / "o"]


@pytest.mark.parametrize(
    ("edit", "expect"),
    [
        (lambda r: r[:1], "one configuration; a socket needs two or more"),
        (lambda r: [*r, r[0]], "line 31: repeats line 1"),
        (
            lambda r: [r[0], r[1].replace(",", ",,", 1), *r[2:]],
            "line 2: joint 2: expected a number, got an empty field",
        ),  # fmt: skip
        (lambda r: [r[0].replace(",", ";").replace(".", ","), *r[1:]], "a decimal comma"),
        (
            lambda r: [r[0], r[1].replace(",", ";"), *r[2:]],
            "line 2: fields separated by semicolons, but line 1 by commas",
        ),  # fmt: skip
        (
            lambda r: [r[0], "1e300" + r[1][r[1].index(",") :], *r[2:]],
            "line 2: a joint angle of 1e+300, beyond 2 pi; 1 of 30 lines: a mistyped value?",
        ),  # fmt: skip
        (
            lambda r: [",".join(c.strip() for c in r[0].split(",")).replace(",", " "), *r[1:]],
            "separated by tabs or spaces",
        ),  # fmt: skip
    ],
)
def test_mukca_socket_files(tmp_path, capsys, edit, expect):
    root = mukca_robot(tmp_path, "\n".join(edit(front_rows())) + "\n")
    refused(capsys, import_mukca(tmp_path, root), str(root / "A" / "hole_0.csv"), expect)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "content",
    [
        b"\xef\xbb\xbf" + "\n".join(front_rows()).encode(),  # a byte-order mark
        "\r\n".join(front_rows()).encode(),  # CRLF
        "\n".join(r.replace(",", "\t") + "\t" for r in front_rows()).encode(),  # tabs, trailing
    ],
)
def test_mukca_socket_files_read_as_written(tmp_path, content):
    from relcal import load_dataset

    root = mukca_robot(tmp_path, content)
    assert main([str(a) for a in import_mukca(tmp_path, root)]) == 0
    assert load_dataset(tmp_path / "o").q.shape == (124, 7)


@pytest.mark.parametrize(("name", "expect"), [("a\nb", "a line break"), (" B", "one id")])
def test_mukca_placement_names(tmp_path, capsys, name, expect):
    root = mukca_robot(tmp_path, "\n".join(front_rows()), name)
    refused(capsys, import_mukca(tmp_path, root), expect)


def test_coincidence_samples_repeated(tmp_path, capsys):
    root = mukca_robot(tmp_path, "\n".join(front_rows()))
    assert main([str(a) for a in import_mukca(tmp_path, root)]) == 0
    samples = tmp_path / "o" / "samples.csv"
    rows = samples.read_text().splitlines()
    copied = rows[5].split(",", 1)[1]  # the fifth sample under a new id
    samples.write_text("\n".join([*rows, "copy," + copied]) + "\n")
    out = tmp_path / "cal"
    refused(
        capsys,
        ["calibrate", tmp_path / "o", "--out", out],
        "line 126: sample 'copy' repeats line 6 (sample 'A/hole_0/004')",
    )
    assert not out.exists()


UR5E_PLAN = "# relcal plan: robot Universal Robots UR5e, joint unit deg\n# relcal robot: ur5e\n"
UR5E_JOINTS = "id,shoulder_pan,shoulder_lift,elbow,wrist1,wrist2,wrist3"


@pytest.mark.parametrize(
    ("rows", "expect"),
    [
        (
            [UR5E_JOINTS + ",elbow", "p1,10,-90,90,-90,-90,0,45"],
            "line 3: header: column(s) elbow appear twice",
        ),  # fmt: skip
        (
            [UR5E_JOINTS, "p1,10,-90,90,-90,-90,0", " p1 ,20,-80,90,-90,-90,0"],
            "line 5: id 'p1' duplicates line 4",
        ),  # fmt: skip
        ([UR5E_JOINTS, ",10,-90,90,-90,-90,0"], "line 4: id: empty; give every pose an id"),
        (
            [UR5E_JOINTS, *(f"p{k},0.{k},-1.5{k},1.4,-1.57,-1.57,0.{k}" for k in range(1, 7))],
            "which looks like radians, but the plan is read in degrees",
        ),  # fmt: skip
        (
            [UR5E_JOINTS, "P001,10,-90,90,-90,-90,0", "p001,20,-80,90,-90,-90,0"],
            "'P001' and 'p001' differ only in case",
        ),  # fmt: skip
    ],
)
def test_capture_plan_files(tmp_path, capsys, rows, expect):
    plan = tmp_path / "plan.csv"
    plan.write_text(UR5E_PLAN + "\n".join(rows) + "\n")
    out = tmp_path / "ds"
    argv = ["capture", plan, "--robot-driver", "manual", "--camera", "folder", "--out", out]
    refused(capsys, argv, str(plan), expect)
    assert not out.exists()


@pytest.mark.parametrize(
    ("text", "expect"),
    [
        ("1e308,1e308", "POS_MM: 1e+308 mm: expected a standard deviation from 0 to 1000 mm"),
        ("0.05,0.01,200", "JOINT_DEG: 200 deg: expected a standard deviation from 0 to 180"),
        ("4_1,0.01", "POS_MM: expected a number, got '4_1': an underscore"),
        ("0.05", "2 or 3 numbers separated by commas, got 1"),
    ],
)
def test_noise_levels_read_strictly_and_bounded(capsys, text, expect):
    from relcal import Noise, RelcalError

    refused(capsys, ["simulate", "--noise", text, "--quiet"], "--noise", expect)
    with pytest.raises(RelcalError, match=expect.replace("+", r"\+")):
        Noise.parse(text)


@pytest.mark.parametrize(
    ("argv", "expect"),
    [
        (["simulate", "--n-poses", "10000000"], "3 or more and at most 10,000"),
        (["study", "--poses", "-5"], "3 or more and at most 10,000"),
        (["study", "--poses", "1_0"], "'1_0': not a file and not a number"),
        (["observability", "--n-poses", "20000"], "3 or more and at most 10,000"),
    ],
)
def test_simulated_pose_counts_bounded(capsys, argv, expect):
    refused(capsys, argv, expect)


def ur5e_rows(unit_line: str | None) -> str:
    rows = [UR5E_JOINTS, *(f"p{k},0.{k},-1.5{k},1.{k},-1.57,-1.57,0.{k}" for k in range(1, 9))]
    return (f"{unit_line}\n" if unit_line else "") + "\n".join(rows) + "\n"


@pytest.mark.parametrize(
    ("first", "options", "expect"),
    [
        (
            "# relcal plan: robot Universal Robots UR5e, joint unit rad",
            ["--joint-unit", "deg"],
            "line 1: the file states joint unit rad, but --joint-unit deg was given",
        ),  # fmt: skip
        (
            "# relcal plan: robot Universal Robots UR5e, joint unit deg",
            [],
            "which looks like radians, but the file's first line states deg",
        ),  # fmt: skip
        (
            None,
            [],
            "which looks like radians, but they are read in deg (the default); give the "
            "angles in deg, or --joint-unit rad",
        ),  # fmt: skip
    ],
)
def test_joint_files_read_in_their_unit(tmp_path, capsys, first, options, expect):
    poses = tmp_path / "poses.csv"
    poses.write_text(ur5e_rows(first))
    argv = ["observability", "--robot", "ur5e", "--poses", poses, *options]
    refused(capsys, argv, str(poses), expect)


def test_joint_files_stating_radians_are_read_in_radians(tmp_path):
    from relcal.data.dataset import read_joints
    from relcal.robot.loading import get_robot

    poses = tmp_path / "poses.csv"
    poses.write_text(ur5e_rows("# relcal plan: robot Universal Robots UR5e, joint unit rad"))
    q = read_joints(poses, get_robot("ur5e"), None)
    assert q[0, 1] == pytest.approx(-1.51)


@pytest.mark.parametrize(
    ("call", "expect"),
    [
        (
            lambda r: r.simulate(r.get_robot("a465"), n_poses=10**7),
            "n_poses: expected a whole number in [3, 10000]",
        ),  # fmt: skip
        (lambda r: r.make_pairs(10**6, "all"), "make_pairs: n_poses=1,000,000 with pairing 'all'"),
        (
            lambda r: r.import_rosbag("x.bag", "out", "/j", pose="/p", options=stop_options(-1)),
            "StopOptions.velocity: expected a number in (0, inf), got -1",
        ),  # fmt: skip
        (lambda r: stop_options(0.01, float("nan")), "StopOptions.settle: expected a finite"),
    ],
)
def test_api_sizes_and_options_refused_before_any_work(call, expect):
    import relcal

    with pytest.raises(relcal.RelcalError, match=re.escape(expect)):
        call(relcal)


def stop_options(velocity: float, settle: float = 0.5):
    from relcal.data.rosbag import StopOptions

    return StopOptions(velocity=velocity, settle=settle)


@pytest.mark.parametrize("command", [["fleet", "calibrate", "plant", "--out", "cal"], ["study"]])
def test_worker_processes_bounded(capsys, command):
    from relcal.limits import max_workers

    too_many = str(max_workers() + 1)
    refused(capsys, [*command, "--workers", too_many], "--workers", "more than this machine")


def test_local_cluster_bounded():
    from relcal import RelcalError
    from relcal.cluster import local_cluster
    from relcal.limits import max_workers

    with pytest.raises(RelcalError, match="workers: .* more than this machine can run"):
        local_cluster(max_workers() + 1)


@pytest.mark.parametrize(
    ("edit", "expect"),
    [
        (
            lambda d: (d / "cal_data.yaml").write_text(
                (d / "cal_data.yaml").read_text() + "- pose: poses/0.yaml\n  image: images/0.png\n"
            ),
            "entry 16: image 'images/0.png' is entry 1's too",
        ),  # fmt: skip
        (
            lambda d: (d / "images" / "1.png").write_text("garbage\n"),
            "1.png: not an image OpenCV can read",
        ),
    ],
)
def test_rct_image_sets(tmp_path, capsys, edit, expect):
    import shutil

    source = tmp_path / "set_eye_in_hand"
    shutil.copytree(DATA / "rct_circle_grid_eye_in_hand", source)
    edit(source)
    out = tmp_path / "out"
    refused(capsys, ["import", "rct-images", source, "--out", out], expect)
    assert not out.exists()


@pytest.mark.parametrize("inside", ["front/x", "."])
def test_an_import_never_writes_into_its_input_folder(tmp_path, capsys, inside):
    """``relcal import mukca DATA --out DATA/front/x`` wrote the dataset into the folder it read;
    every importer now refuses an --out inside its input folder, as fleet does."""
    from relcal.cli import main

    source = tmp_path / "panda"
    (source / "front").mkdir(parents=True)
    (source / "front" / "hole_0.csv").write_text("1,2,3,4,5,6,7\n")
    out = source / inside
    code = main(["import", "mukca", str(source), "--urdf", str(tmp_path / "r.urdf"),
                 "--out", str(out)])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "inside the mukca input folder" in err or "which this run reads" in err, err
    assert sorted(p.name for p in source.rglob("*")) == ["front", "hole_0.csv"]
