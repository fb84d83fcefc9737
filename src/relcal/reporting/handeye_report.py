"""What ``relcal handeye`` prints and writes: the results document, the table of every method's
held-out errors, and the files a cell loads (``handeye.yaml``, a ROS 2 launch file publishing the
transform with tf2's ``static_transform_publisher``, a URDF joint, an easy_handeye2 calibration
file, and an HTML report)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.calibration.handeye_closed import TITLES
from relcal.calibration.handeye_job import REFINED, Delivered, HandEye
from relcal.io import yaml_text
from relcal.reporting.documents import verdict_document

MODE_WORDS = {
    "eye_in_hand": "eye-in-hand: the camera on the flange",
    "eye_to_hand": "eye-to-hand: a fixed camera, the board on the flange",
    "robot_world": "robot-world: the camera or marker on the flange, and the world frame",
}


def title(method: str) -> str:
    """A method's name for a person."""
    return "refined (relcal)" if method == REFINED else TITLES[method]


def _frame(t: np.ndarray) -> dict:
    """``xyz_m`` and ``rpy_deg`` (calibrate's ``handeye`` form) and the quaternion, x first."""
    xyz, rpy = tf.to_xyz_rpy(t)
    return {
        "xyz_m": [float(v) for v in xyz],
        "rpy_deg": [float(np.degrees(v)) for v in rpy],
        "quaternion_xyzw": [float(v) for v in Rotation.from_matrix(t[:3, :3]).as_quat()],
    }


def _nan_none(values) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in values]


def delivered_document(d: Delivered) -> dict:
    """One delivered transform: frames, values, standard deviations (``xyz_mm``; ``rotation_deg``
    about the parent's x, y, z axes; None where not determined), what is undetermined or
    held."""
    out = {"parent": d.parent, "child": d.child, **_frame(d.transform)}
    if d.undetermined:  # never a confident number: the values are not given
        out["xyz_m"] = out["rpy_deg"] = out["quaternion_xyzw"] = None
    out["std"] = {
        "xyz_mm": _nan_none(np.asarray(d.xyz_std) * 1e3),
        "rotation_deg": _nan_none(np.degrees(d.rotation_std)),
    }
    out["undetermined"] = list(d.undetermined)
    out["held_at_guess"] = list(d.held)
    out["weak"] = list(d.weak)
    return out


def validation_document(he: HandEye) -> dict | None:
    """Every method's held-out errors on the same samples, with intervals, the ratios of the
    refined estimate to each, the favoured method and the per-sample errors."""
    val = he.validation
    if val is None:
        return None
    methods = []
    for m in val.errors:
        entry = {"method": m, "title": title(m), **val.summary(m)}
        if m != REFINED:
            entry["refined_over_it"] = val.ratio(m)
        entry["failures"] = val.failures.get(m, [])
        methods.append(entry)
    samples = []
    for k, i in enumerate(val.samples):
        row: dict = {"id": he.ids[int(i)], "fold": int(val.fold[k]) + 1}
        for m, err in val.errors.items():
            e = err[k]
            cell = {
                "position_mm": float(np.linalg.norm(e[:3]) * 1e3) if np.all(np.isfinite(e))
                else None,
                "orientation_deg": float(np.degrees(np.linalg.norm(e[3:])))
                if np.all(np.isfinite(e)) else None,
            }  # fmt: skip
            if val.px is not None:
                cell["px"] = float(val.px[m][k]) if np.isfinite(val.px[m][k]) else None
            row[m] = cell
        samples.append(row)
    samples.sort(key=lambda r: r["id"])
    return {
        "what": "per held-out sample, the predicted pose of the camera (or marker) W F X against "
        "the measured one"
        + (", and the reprojection RMS of its image" if val.px is not None else "")
        + "; every method refitted on the other folds' samples",
        "criterion": val.criterion,
        "n_folds": val.n_folds,
        "n_samples": len(val.samples),
        "methods": methods,
        "favoured": val.favoured(),
        "samples": samples,
    }


def handeye_document(he: HandEye, dataset=None) -> dict:
    """Everything a hand-eye job found, JSON-ready (``results.json``)."""
    fit = he.fit
    doc: dict = {
        "job": "handeye",
        "mode": he.mode,
        "dataset": None if dataset is None else str(dataset.root),
        "robot": None if dataset is None else dataset.model.name,
        "robot_id": None if dataset is None else dataset.robot_id,
        "flange_poses_from": he.source,
        "n_samples": len(he.ids),
        "n_used": int(fit.used.sum()),
        "rejected": [{"id": i, "reason": r} for i, r in he.rejected.items()],
        "outliers": [{"id": i, "reason": r} for i, r in he.outliers.items()],
        "exported": he.exported,
        "frames": dict(he.frames),
    }
    for d in he.delivered:
        doc[d.key] = delivered_document(d)
    if he.mode != "robot_world":
        doc["world"] = None
    doc["refined"] = {
        "converged": bool(fit.converged),
        "handeye_X": _frame(fit.handeye),
        "world_W": _frame(fit.world),
        "noise_model": None
        if fit.noise is None
        else {
            "std_position_mm": [float(v) for v in np.sqrt(np.diag(fit.noise))[:3] * 1e3],
            "std_orientation_deg": [float(v) for v in np.degrees(np.sqrt(np.diag(fit.noise))[3:])],
            "frame": "the board's" if he.mode == "eye_to_hand" else "the camera's (or marker's)",
            "what": "each image's pose error beyond its pixels (flange poses, repeatability)"
            if fit.pixel_sigma is not None
            else "each measured pose's error",
        },
        "pixel_sigma": fit.pixel_sigma,
        "held": list(fit.held),
    }
    if he.camera is not None and hasattr(he.camera, "to_dict"):
        doc["refined"]["camera"] = he.camera.to_dict()
    doc["closed_forms"] = [
        {
            "method": a.method,
            "title": TITLES[a.method],
            "ok": a.ok,
            "failure": a.failure,
            "handeye_X": None if a.handeye is None else _frame(a.handeye),
            "world_W": None if a.world is None else _frame(a.world),
        }
        for a in he.closed
    ]
    doc["closed_form_samples"] = {
        "used": len(he.selection.used),
        "left_out": [
            {"id": he.ids[i], "reason": r} for i, r in sorted(he.selection.left_out.items())
        ],
    }
    doc["findings"] = list(he.findings)
    doc["validation"] = validation_document(he)
    doc["verdict"] = verdict_document(he.verdict)
    doc["settings"] = dict(he.settings)
    return doc


def _fmt(value, spec: str = ".3f") -> str:
    return "-" if value is None or not np.isfinite(value) else format(value, spec)


def _interval(ci, spec: str = ".3f") -> str:
    return "" if not ci else f" [{_fmt(ci[0], spec)}, {_fmt(ci[1], spec)}]"


def handeye_text(doc: dict, per_sample: bool = False) -> str:
    """The summary a person reads: the delivered transform(s), the table of held-out errors of
    every method, what the data leave weak, the verdict."""
    lines = [
        f"hand-eye, {MODE_WORDS[doc['mode']]}; flange poses from {doc['flange_poses_from']}",
        f"samples: {doc['n_samples']}, {doc['n_used']} used"
        + (f", {len(doc['rejected'])} not posed" if doc["rejected"] else "")
        + (f", {len(doc['outliers'])} bad frame(s) left out" if doc["outliers"] else ""),
    ]
    for o in doc["outliers"]:
        lines.append(f"  bad frame {o['id']}: {o['reason']}")
    for key in ("handeye", "world"):
        d = doc.get(key)
        if not d:
            continue
        std = d["std"]
        if d["xyz_m"] is None:
            lines.append(f"{d['parent']} -> {d['child']}: not determined by these data")
        else:
            lines.append(
                f"{d['parent']} -> {d['child']}: xyz "
                + " ".join(f"{v * 1e3:.3f}" for v in d["xyz_m"])
                + " mm (std "
                + " ".join(_fmt(v) for v in std["xyz_mm"])
                + "), rpy "
                + " ".join(f"{v:.4f}" for v in d["rpy_deg"])
                + " deg; rotation std about x y z "
                + " ".join(_fmt(v, ".4f") for v in std["rotation_deg"])
                + " deg"
            )
        for u in d["undetermined"]:
            lines.append(f"  not determined: {u}")
        for u in d["held_at_guess"]:
            lines.append(f"  held at the guess of dataset.yaml: {u}")
        for u in d["weak"]:
            lines.append(f"  weak: {u}")
    if doc["exported"] not in (None, REFINED):
        lines.append(f"exported: {title(doc['exported'])} (the held-out samples favour it)")
    for f in doc["findings"]:
        lines.append(f"motions: {f}")
    failed = [c for c in doc["closed_forms"] if not c["ok"]]
    for c in failed:
        lines.append(f"closed form {c['title']}: failed: {c['failure']}")
    left = doc["closed_form_samples"]["left_out"]
    if left:
        lines.append(
            f"closed forms on {doc['closed_form_samples']['used']} samples; left out: "
            + "; ".join(f"{x['id']} ({x['reason']})" for x in left[:4])
            + (" ..." if len(left) > 4 else "")
        )
    val = doc["validation"]
    if val is None:
        lines.append("held-out: none (too few samples)")
    else:
        px = val["criterion"] == "px"
        lines.append(
            f"held-out, {val['n_folds']} folds over {val['n_samples']} samples (predicted "
            "camera/marker pose W F X against the measured one"
            + (", and the image's reprojection" if px else "")
            + "; RMS with 95% interval):"
        )
        head = f"  {'method':<18} {'position mm':>24} {'orientation deg':>24}"
        head += f" {'reprojection px':>24}" if px else ""
        head += "  refined/it"
        lines.append(head)
        for m in val["methods"]:
            row = f"  {m['title']:<18}"
            for key in ("position_mm", "orientation_deg", *(("px",) if px else ())):
                s = m.get(key)
                row += f" {(_fmt(s['rms']) + _interval(s.get('ci95'))) if s else '-':>24}"
            r = m.get("refined_over_it")
            key = "px" if px else "position_mm"
            if r and key in r:
                row += f"  {r[key]['after_over_before']:.3f}{_interval(r[key]['ci95'])}"
            if m["failures"]:
                row += f"  (failed in {len(m['failures'])} fold(s))"
            lines.append(row)
        lines.append(f"the data favour: {title(val['favoured'])}")
        if per_sample:
            lines.append("  per held-out sample (position mm / orientation deg):")
            for s in val["samples"]:
                cells = [
                    f"{title(m['method'])[:10]} {_fmt(s[m['method']]['position_mm'])}/"
                    f"{_fmt(s[m['method']]['orientation_deg'])}"
                    for m in val["methods"][:3]
                ]
                lines.append(f"  {s['id']:<10} fold {s['fold']}: " + ", ".join(cells))
    lines.append(f"verdict: {doc['verdict']['text']}")
    for w in doc["verdict"]["warnings"]:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)


# --- files a cell loads --------------------------------------------------------------------------


def _held_out_line(doc: dict) -> dict | None:
    val = doc.get("validation")
    if not val:
        return None
    m = next(x for x in val["methods"] if x["method"] == (doc["exported"] or REFINED))
    out = {"method": m["title"], "n_samples": m["n_samples"], "folds": val["n_folds"]}
    for key in ("position_mm", "orientation_deg", "px"):
        if m.get(key):
            out[f"{key}_rms"] = m[key]["rms"]
    return out


def handeye_yaml(he: HandEye, doc: dict) -> str:
    """``handeye.yaml``: each delivered transform with its parent and child frames, ``xyz`` (m),
    ``quaternion`` (x, y, z, w) and ``rpy`` (rad, URDF's fixed-axis roll, pitch, yaw), its
    standard deviations, and the held-out error of the exported estimate."""
    data: dict = {"mode": he.mode, "estimate": title(he.exported or REFINED)}
    for d in (*he.delivered, *((he.marker,) if he.marker is not None else ())):
        xyz, rpy = tf.to_xyz_rpy(d.transform)
        data[d.key] = {
            "parent": d.parent,
            "child": d.child,
            "xyz": [float(v) for v in xyz],
            "quaternion": [float(v) for v in Rotation.from_matrix(d.transform[:3, :3]).as_quat()],
            "rpy": [float(v) for v in rpy],
            "std": {
                "xyz_mm": _nan_none(np.asarray(d.xyz_std) * 1e3),
                "rotation_deg": _nan_none(np.degrees(d.rotation_std)),
            },
        }
        if d.held:
            data[d.key]["held_at_guess"] = list(d.held)
        if d.weak:
            data[d.key]["weak"] = list(d.weak)
    data["held_out"] = _held_out_line(doc)
    head = (
        "# relcal handeye: the transform(s) below, child frame in parent frame; xyz in m,\n"
        "# quaternion x, y, z, w; rpy in rad (URDF: R = Rz(yaw) Ry(pitch) Rx(roll)).\n"
    )
    if he.marker is not None:
        head += (
            "# marker: the board on the flange, a by-product of the eye-to-hand fit (the guess\n"
            "# relcal calibrate --handeye starts from).\n"
        )
    return head + yaml_text(data)


def launch_file(he: HandEye) -> str:
    """A ROS 2 launch file (Python) publishing each delivered transform with tf2's
    ``static_transform_publisher`` (:func:`relcal.reporting.ros2.static_transform_node`)."""
    import json

    from relcal.reporting.ros2 import static_transform_node

    nodes = [
        static_transform_node(
            d.transform, json.dumps(d.parent), json.dumps(d.child), f"relcal_{d.key}", 12
        )
        for d in he.delivered
    ]
    return (
        '"""Publishes the hand-eye calibration of relcal handeye as static transforms (tf2)."""\n\n'
        "from launch import LaunchDescription\n"
        "from launch_ros.actions import Node\n\n\n"
        "def generate_launch_description():\n"
        "    return LaunchDescription(\n"
        "        [\n" + "".join(node + ",\n" for node in nodes) + "        ]\n    )\n"
    )


def urdf_snippet(he: HandEye) -> str:
    """URDF ``<joint>`` elements (fixed) of the delivered transforms, in a minimal ``<robot>`` with
    their links, so that the file loads as a URDF; copy the joints into a robot's own URDF."""
    from xml.sax.saxutils import quoteattr

    links: list[str] = []
    joints = []
    for d in he.delivered:
        xyz, rpy = tf.to_xyz_rpy(d.transform)
        for link in (d.parent, d.child):
            if link not in links:
                links.append(link)
        joints.append(
            f'  <joint name={quoteattr(f"{d.parent}_to_{d.child}")} type="fixed">\n'
            f"    <parent link={quoteattr(d.parent)}/>\n"
            f"    <child link={quoteattr(d.child)}/>\n"
            f'    <origin xyz="{" ".join(repr(float(v)) for v in xyz)}" '
            f'rpy="{" ".join(repr(float(v)) for v in rpy)}"/>\n'
            "  </joint>\n"
        )
    return (
        '<?xml version="1.0"?>\n'
        "<!-- relcal handeye: copy the joint(s) into the robot's URDF -->\n"
        '<robot name="relcal_handeye">\n'
        + "".join(f"  <link name={quoteattr(link)}/>\n" for link in links)
        + "".join(joints)
        + "</robot>\n"
    )


def easy_handeye2_file(he: HandEye) -> str:
    """An easy_handeye2-style calibration file (``parameters``, ``transform``): eye-in-hand the
    effector to the tracking base (camera), eye-on-base the robot base to the camera."""
    d = he.delivered[0]
    f = he.frames
    q = Rotation.from_matrix(d.transform[:3, :3]).as_quat()
    t = d.transform[:3, 3]
    data = {
        "parameters": {
            "name": "relcal_handeye",
            "calibration_type": "eye_on_base" if he.mode == "eye_to_hand" else "eye_in_hand",
            "robot_base_frame": f["base"],
            "robot_effector_frame": f["flange"],
            "tracking_base_frame": f["camera"],
            "tracking_marker_frame": f["marker"] if he.mode == "eye_to_hand" else f["world"],
            "freehand_robot_movement": False,
        },
        "transform": {
            "translation": {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
            "rotation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])},
        },
    }
    return yaml_text(data)


def handeye_files(he: HandEye, doc: dict) -> dict[str, str]:
    """The output folder's files: ``handeye.yaml``, ``handeye.launch.py``, ``handeye.urdf``,
    ``handeye.calib`` (easy_handeye2) and ``results.json``; only ``results.json`` when the
    estimate is refused (directions not determined)."""
    from relcal.io import json_text

    files = {"results.json": json_text(doc)}
    if he.exported is None:
        return files
    files["handeye.yaml"] = handeye_yaml(he, doc)
    files["handeye.launch.py"] = launch_file(he)
    files["handeye.urdf"] = urdf_snippet(he)
    files["handeye.calib"] = easy_handeye2_file(he)
    return files


def handeye_html(doc: dict) -> str:
    """A self-contained HTML report of the document: the verdict, the delivered transform(s) with
    what the motions leave weak, every method's held-out errors side by side (RMS with 95 %
    intervals, the refined estimate over each, the method the data favour), each held-out
    sample, every closed form's answer or why it failed, and the samples left out."""
    from relcal.reporting.htmlkit import bullet_list, cards, page, paragraph, section

    verdict = doc["verdict"]
    val = doc["validation"]
    px = val is not None and val["criterion"] == "px"
    exported = title(doc["exported"]) if doc["exported"] else "nothing"
    summary = [("verdict", verdict["code"], ""), ("exported", exported, "")]
    if val:
        summary.append(("the data favour", title(val["favoured"]), f"{val['n_folds']} folds"))
    sections = [
        section(
            "verdict",
            "Verdict",
            cards(summary),
            paragraph(verdict["text"]),
            bullet_list(verdict["warnings"], "no warnings"),
        ),
        section("transform", "Transform", *_transform_parts(doc)),
    ]
    if val:
        sections.append(section("held-out", "Held-out errors by method", *_method_parts(val, px)))
        sections.append(section("samples", "Held-out samples", *_sample_parts(val, px)))
    sections.append(section("closed-forms", "Closed forms", *_closed_parts(doc)))
    meta = [("mode", doc["mode"]), ("dataset", str(doc["dataset"]))]
    meta.append(("samples", str(doc["n_used"])))
    return page("relcal hand-eye calibration", meta, sections)


def _transform_parts(doc: dict) -> list:
    from relcal.reporting.htmlkit import bullet_list, paragraph, table

    rows, notes = [], []
    for key in ("handeye", "world"):
        d = doc.get(key)
        if not d:
            continue
        vals = d["xyz_m"] and [f"{v * 1e3:.3f}" for v in d["xyz_m"]]
        rows.append(
            [
                f"{d['parent']} -> {d['child']}",
                " ".join(vals) if vals else "not determined",
                " ".join(f"{v:.4f}" for v in d["rpy_deg"]) if d["rpy_deg"] else "not determined",
                " ".join(_fmt(v) for v in d["std"]["xyz_mm"]),
                " ".join(_fmt(v, ".4f") for v in d["std"]["rotation_deg"]),
            ]
        )
        notes += [f"not determined: {u}" for u in d["undetermined"]]
        notes += [f"held at the guess of dataset.yaml: {u}" for u in d["held_at_guess"]]
        notes += [f"weak: {u}" for u in d["weak"]]
    head = ["frames", "xyz mm", "rpy deg", "std mm", "rotation std deg (about x y z)"]
    return [
        paragraph(f"Flange poses from {doc['flange_poses_from']}."),
        table(head, rows),
        bullet_list(
            notes + [f"motions: {f}" for f in doc["findings"]],
            "the motions determine every direction",
        ),  # fmt: skip
    ]


def _method_parts(val: dict, px: bool) -> list:
    from relcal.reporting.htmlkit import paragraph, table

    key = "px" if px else "position_mm"
    head = ["method", "position mm", "orientation deg", *(["reprojection px"] if px else [])]
    head += [f"refined / it ({'px' if px else 'position'})", "samples", "failed folds"]
    body = []
    for m in val["methods"]:
        cells = [m["title"] + (" (favoured)" if m["method"] == val["favoured"] else "")]
        for k in ("position_mm", "orientation_deg", *(("px",) if px else ())):
            s = m.get(k)
            cells.append((_fmt(s["rms"]) + _interval(s.get("ci95"))) if s else "-")
        r = (m.get("refined_over_it") or {}).get(key)
        cells.append(f"{r['after_over_before']:.3f}{_interval(r['ci95'])}" if r else "-")
        cells += [m["n_samples"], len(m["failures"])]
        body.append(cells)
    failures = [f"{m['title']}: {f}" for m in val["methods"] for f in m["failures"]]
    parts = [
        paragraph(val["what"] + "; RMS with 95 % bootstrap intervals, ranked by "
                  + ("the reprojection error" if px else "the position error") + "."),
        table(head, body, "num"),
        paragraph(f"The data favour: {title(val['favoured'])}."),
    ]  # fmt: skip
    if failures:
        from relcal.reporting.htmlkit import bullet_list

        parts.append(bullet_list(failures, ""))
    return parts


def _sample_parts(val: dict, px: bool) -> list:
    from relcal.reporting.htmlkit import paragraph, table

    methods = [m["method"] for m in val["methods"]]
    head = ["sample", "fold"] + [title(m) for m in methods]
    unit = "px" if px else "position mm / orientation deg"
    body = []
    for s in val["samples"]:
        row = [s["id"], s["fold"]]
        for m in methods:
            c = s[m]
            if px:
                row.append(_fmt(c.get("px")))
            else:
                row.append(f"{_fmt(c['position_mm'])} / {_fmt(c['orientation_deg'])}")
        body.append(row)
    return [paragraph(f"Each held-out sample's error ({unit}) under each method."),
            table(head, body, "num")]  # fmt: skip


def _closed_parts(doc: dict) -> list:
    from relcal.reporting.htmlkit import bullet_list, paragraph, table

    body = []
    for c in doc["closed_forms"]:
        x = c["handeye_X"]
        body.append(
            [
                c["title"],
                " ".join(f"{v * 1e3:.3f}" for v in x["xyz_m"]) if x else "-",
                " ".join(f"{v:.4f}" for v in x["rpy_deg"]) if x else "-",
                "ok" if c["ok"] else f"failed: {c['failure']}",
            ]
        )
    left = doc["closed_form_samples"]["left_out"]
    return [
        paragraph(
            f"OpenCV's closed forms on {doc['closed_form_samples']['used']} samples, all of "
            "them (X: flange to camera or marker, xyz mm, rpy deg)."
        ),
        table(["method", "X xyz mm", "X rpy deg", "status"], body),
        bullet_list([f"{x['id']}: {x['reason']}" for x in left], "no sample left out"),
        bullet_list(
            [f"bad frame {o['id']}: {o['reason']}" for o in doc["outliers"]]
            + [f"not posed {o['id']}: {o['reason']}" for o in doc["rejected"]],
            "no bad frame",
        ),
    ]
