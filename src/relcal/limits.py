"""Bounds on what relcal reads and allocates, each checked before the work with a message that
names the input, the size found, the limit, and how to go on.

- **Input files** (:func:`check_input_size`, :func:`read_input`): a file larger than the cap of
  its kind is refused before a byte is read, a device (``/dev/zero``) is refused, and a pipe is
  read only up to the cap. The caps are generous (a calibration's CSV of 200 MB holds millions of
  samples) and each can be raised with an environment variable, ``RELCAL_MAX_<KIND>_MB``
  (``RELCAL_MAX_CSV_MB=500``).
- **YAML keys** (:func:`check_yaml_nodes`): a mapping that gives a key twice is refused (YAML
  forbids it; a parser would silently keep one value).
- **YAML aliases** (:func:`check_yaml_nodes`): a document whose aliases expand to more than
  ``RELCAL_MAX_YAML_ALIAS_NODES`` nodes beyond its own (a "billion laughs" file: 471 bytes that
  expand to 10^9 values), or that refers to itself, or nests deeper than ``MAX_YAML_DEPTH``, is
  refused before anything walks it.
- **Memory** (:func:`check_memory`): a computation whose size follows from the input (all
  pairs of N samples is quadratic; the board formulation, ``--pairs auto`` above 300 samples, is
  linear) states its need first, for the formulation it will use; above ``RELCAL_MAX_MEMORY_MB``
  (default 2048) it is refused with the remedy.

Nothing here imports NumPy: the command line checks sizes before loading anything heavy.
"""

from __future__ import annotations

import os
from pathlib import Path

from relcal.errors import RelcalError

MAX_SIMULATED_POSES = 10_000  # each is reached by inverse kinematics: about 20 ms, one at a time


def max_workers() -> int:
    """The most local worker processes a run may start: 4 per core of this machine, at least 8
    (each is a Python process of some 200 MB with NumPy and SciPy loaded; a thousand of them on
    two cores is a machine brought to a halt, not a faster run)."""
    return max(8, 4 * (os.cpu_count() or 1))


def check_workers(workers: int, name: str = "workers") -> None:
    """Refuse more local worker processes than :func:`max_workers`, naming ``name``."""
    if workers > max_workers():
        raise RelcalError(f"{name}: {workers_excess(workers)}")


def workers_excess(workers: int) -> str:
    """Why ``workers`` local processes are too many, with the most this machine takes."""
    limit = max_workers()
    return (
        f"{workers} worker processes, more than this machine can run ({limit}: 4 per core, "
        f"{os.cpu_count() or 1} cores; each a Python process of some 200 MB); give at most "
        f"{limit}, or run on a Dask cluster (--scheduler) for more"
    )


MB = 1_000_000

# the default cap per kind of input file, in MB; RELCAL_MAX_<KIND>_MB overrides
INPUT_CAPS_MB = {
    "csv": 200,  # samples, targets, joint lists
    "yaml": 20,  # dataset.yaml, robot models, boards, cameras, robot_cal_tools files
    "urdf": 50,
    "image": 500,  # one image file
    "text": 20,  # --holdout-ids @file and other plain lists
}
YAML_ALIAS_NODES = 100_000  # nodes aliases may add to a YAML document
MAX_YAML_DEPTH = 500  # nesting of YAML collections
MEMORY_MB = 2048  # default bound of a computation's estimated memory


def _env_number(name: str, default: float) -> float:
    text = os.environ.get(name)
    if text in (None, ""):
        return default
    try:
        value = float(text)
    except ValueError:
        raise RelcalError(f"environment variable {name}={text!r}: expected a number") from None
    if not value > 0:
        raise RelcalError(f"environment variable {name}={text!r}: expected a number above 0")
    return value


def input_cap(kind: str) -> int:
    """The size cap (bytes) of an input file of ``kind`` (``csv``, ``yaml``, ``urdf``,
    ``image``, ``text``)."""
    default = INPUT_CAPS_MB[kind]
    return int(_env_number(f"RELCAL_MAX_{kind.upper()}_MB", default) * MB)


def check_input_size(path: str | Path, kind: str) -> None:
    """Refuse ``path`` before reading it when it is larger than the cap of its ``kind``, or a
    device or socket (``/dev/zero`` never ends, ``/dev/random`` is noise: neither is a file of
    data); a missing or unreadable file is left to the reader's own message. A pipe has no
    size: read it with :func:`read_input`, which stops at the cap."""
    import stat

    try:
        info = os.stat(path)
    except OSError:
        return
    if stat.S_ISCHR(info.st_mode) or stat.S_ISBLK(info.st_mode) or stat.S_ISSOCK(info.st_mode):
        raise RelcalError(
            f"{path}: a device, not a file (not read: it may never end); give the {kind} file "
            "itself"
        )
    size = info.st_size
    cap = input_cap(kind)
    if size > cap:
        raise RelcalError(
            f"{path}: {_megabytes(size)}, above the {_megabytes(cap)} limit for {kind} input "
            f"files (not read); a wrong file? If it is right, raise the limit with "
            f"RELCAL_MAX_{kind.upper()}_MB"
        )


def read_input(path: str | Path, kind: str) -> bytes:
    """The bytes of the input file ``path`` of ``kind``: refused as :func:`check_input_size`
    does, and read at most up to the cap (a pipe or a file that grows while read stops there:
    refused, not read to the end). ``OSError`` is left to the caller's message."""
    check_input_size(path, kind)
    cap = input_cap(kind)
    with open(path, "rb") as handle:
        data = handle.read(cap + 1)
    if len(data) > cap:
        raise RelcalError(
            f"{path}: more than the {_megabytes(cap)} limit for {kind} input files (read "
            f"stopped there); a wrong file? If it is right, raise the limit with "
            f"RELCAL_MAX_{kind.upper()}_MB"
        )
    return data


def _megabytes(n: float) -> str:
    return f"{n / MB:,.1f} MB" if n >= MB else f"{n / 1000:,.1f} kB"


def check_yaml_nodes(path: str | Path, root) -> None:
    """Refuse a YAML node tree whose aliases expand beyond the bound, that refers to itself,
    or that nests too deeply (``root``: a ``yaml.Node``). Linear in the distinct nodes."""
    import yaml

    bound = int(_env_number("RELCAL_MAX_YAML_ALIAS_NODES", YAML_ALIAS_NODES))

    def children(node) -> list:
        if isinstance(node, yaml.MappingNode):
            return [n for pair in node.value for n in pair]
        if isinstance(node, yaml.SequenceNode):
            return list(node.value)
        return []

    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    on_path: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            kids = children(node)
            size[key] = 1 + sum(size[id(c)] for c in kids)
            depth[key] = 1 + max((depth[id(c)] for c in kids), default=0)
            if depth[key] > MAX_YAML_DEPTH:
                raise RelcalError(
                    f"{path} line {node.start_mark.line + 1}: YAML nested more than "
                    f"{MAX_YAML_DEPTH} levels deep; not a relcal file"
                )
            if size[key] - len(size) > bound:
                raise RelcalError(
                    f"{path}: YAML aliases (*name) expand this document beyond "
                    f"{len(size) + bound:,} values from {len(size):,} written out: refused (a "
                    "'billion laughs' file?); write the values out, or raise "
                    "RELCAL_MAX_YAML_ALIAS_NODES"
                )
            continue
        if key in size:
            continue
        if isinstance(node, yaml.MappingNode):
            _check_unique_keys(path, node)
        on_path.add(key)
        stack.append((node, True))
        for child in children(node):
            if id(child) in on_path:
                raise RelcalError(
                    f"{path} line {child.start_mark.line + 1}: a YAML alias that refers to "
                    "itself (a recursive structure); not a relcal file"
                )
            if id(child) not in size:
                stack.append((child, False))


def _check_unique_keys(path: str | Path, node) -> None:
    """Refuse a mapping that gives one key twice (YAML forbids it; PyYAML would keep the last
    silently, and the first value, the one a reader sees first, would be ignored)."""
    seen: dict[str, int] = {}
    for key, _ in node.value:
        if key.tag == "tag:yaml.org,2002:merge" or not hasattr(key, "value"):
            continue
        if not isinstance(key.value, str):
            continue
        line = key.start_mark.line + 1
        if key.value in seen:
            from relcal.errors import printable

            raise RelcalError(
                f"{path} line {line}: key '{printable(key.value, 60)}' given twice (first on "
                f"line {seen[key.value]}); YAML keeps only one of them: delete or merge one"
            )
        seen[key.value] = line


def memory_limit() -> int:
    """The memory (bytes) a computation may plan for: ``RELCAL_MAX_MEMORY_MB`` (default 2048)."""
    return int(_env_number("RELCAL_MAX_MEMORY_MB", MEMORY_MB) * 2**20)


def check_memory(need: float, what: str, remedy: str) -> None:
    """Refuse a computation whose estimated peak memory ``need`` (bytes) exceeds the limit;
    ``what`` names the computation and its size, ``remedy`` how to go on."""
    limit = memory_limit()
    if need > limit:
        raise RelcalError(
            f"{what} would need about {_size(need)} of memory, above the limit of "
            f"{_size(limit)} (RELCAL_MAX_MEMORY_MB); {remedy}"
        )


def _size(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


AUTO_ALL_PAIRS = 300  # samples whose all pairs the hand-eye guess and verify's checks may form


def resolve_pairing(pairing: str, n_samples: int, formulation: str = "invariant") -> str:
    """The pairing ``auto`` stands for: for camera (or mocap) poses, ``formulation``
    ``invariant`` (what calibrate fits), ``board``, each pose against ``W F(q) X`` with the
    world (board) transform ``W`` estimated, whatever the number of samples (the
    maximum-likelihood form of independent pose noise, one measurement per sample, invariant to
    the order of the samples: docs/explanation/relative-formulation.md); for the base-frame
    formulations of a simulation (``published``, ``absolute``), which cannot take a board, all
    pairs up to :data:`AUTO_ALL_PAIRS` samples (``board`` above, refused by them). Any other
    pairing is itself; anything but one of the pairings' names is refused, naming
    ``pairing``."""
    names = ("auto", "all", "consecutive", "star", "board")
    if not isinstance(pairing, str) or pairing not in names:
        from relcal.checks import describe  # (NumPy: only on this error path)
        from relcal.errors import ArgumentError

        raise ArgumentError(
            f"pairing: unknown {describe(pairing)}; expected one of "
            + ", ".join(repr(n) for n in names)
        )
    if pairing != "auto":
        return pairing
    if formulation in ("invariant", "board"):
        return "board"
    return "all" if n_samples <= AUTO_ALL_PAIRS else "board"


def pair_count(n_samples: int, pairing: str) -> int:
    """Measurements of ``n_samples`` samples under ``pairing``: pairs (``all`` is quadratic), or
    one per sample (``board``)."""
    pairing = resolve_pairing(pairing, n_samples)
    if pairing == "all":
        return n_samples * (n_samples - 1) // 2
    if pairing == "board":
        return n_samples
    return max(n_samples - 1, 0)


# Measured peaks of a calibration and its results on synthetic A465 sets (42 + 6 parameters):
# - all pairs: 163 MB at 100 samples, 345 MB at 300, 922 MB at 500: 6.3 KB per pair of the whole
#   dataset (residuals, Jacobians and their weighted copies, 3 x 8 bytes per row and parameter);
# - consecutive or star pairs: the covariance whitens the noise of a chain through the training
#   samples with a dense SVD of (6 n)^2 numbers: 1.55 GB at 1000 samples (750 training), about 8
#   such matrices;
# - board: one measurement per sample and a block-diagonal covariance, no dense matrix of the
#   samples: linear. bench/scale.py measured peaks (RSS of a whole `relcal calibrate`, 42 + 12
#   parameters) of 218 MB at 1000 samples, 299 MB at 3000 and 393 MB at 10,000: about 20 KB per
#   sample, 370 bytes per sample and parameter (residuals, Jacobians, the linearisation, the
#   noise model's moments and their copies).
# The peak is the larger of the two terms (they come at different steps).
PAIR_BYTES_PER_PARAMETER = 6 * 8 * 3
BOARD_BYTES_PER_PARAMETER = 400
CHAIN_COPIES = 8
BASE_BYTES = 150 * 2**20


def calibration_memory(
    n_samples: int, pairing: str, n_params: int, n_train: int | None = None
) -> float:
    """Estimated peak memory (bytes) of a calibration of ``n_samples`` samples (``n_train`` of
    them training, default all) with ``n_params`` parameters (geometry, non-geometric candidates
    and hand-eye) under ``pairing`` (``auto`` resolved by ``n_samples``)."""
    n_train = n_samples if n_train is None else n_train
    pairing = resolve_pairing(pairing, n_samples)
    if pairing == "board":  # + the board transform's 6-vector
        return BASE_BYTES + n_samples * (n_params + 6) * BOARD_BYTES_PER_PARAMETER
    pairs = pair_count(n_samples, pairing) * n_params * PAIR_BYTES_PER_PARAMETER
    chain = CHAIN_COPIES * (6.0 * n_train) ** 2 * 8
    return BASE_BYTES + max(pairs, chain)


def check_calibration_memory(
    n_samples: int, pairing: str, n_params: int, where: str, n_train: int | None = None
) -> None:
    """Refuse a calibration whose pairs or covariance would not fit in the memory limit,
    before allocating them, naming the sample count, the estimate and the remedy."""
    need = calibration_memory(n_samples, pairing, n_params, n_train)
    if need <= memory_limit():
        return
    used = resolve_pairing(pairing, n_samples)
    pairs = pair_count(n_samples, used)
    limit = memory_limit()
    n_train = n_samples if n_train is None else n_train
    cheaper = calibration_memory(n_samples, "board", n_params, n_train)
    per_sample = (n_params + 6) * BOARD_BYTES_PER_PARAMETER
    largest = max(limit - BASE_BYTES, 0) / per_sample  # samples with the board formulation
    fewer = f"calibrate at most about {int(largest):,} samples"
    if used != "board":
        remedy = (
            "use --pairing board or auto, the default (pairing='board' or 'auto' in Python: one "
            f"measurement per sample, the information of all pairs, about {_size(cheaper)})"
        )
        if cheaper > limit:
            remedy += f", which is still above the limit: {fewer}"
    else:
        remedy = fewer
    shown = pairing if pairing == used else f"{pairing} ({used})"
    count = f"{pairs:,} measurements" if used == "board" else f"{pairs:,} pairs"
    check_memory(
        need,
        f"{where}: {n_samples:,} samples with --pairing {shown} ({count}, {n_params} parameters)",
        remedy + "; or raise RELCAL_MAX_MEMORY_MB if the machine has the memory",
    )


# Coincidence data estimate a point per group: the identification Jacobian has 3 rows per sample
# (and one per known distance) and 3 columns per group besides the robot's, and is dense.
# Measured on simulated UR5e coincidence sets (`relcal simulate --coincidence`, 2 sockets per
# placement, `relcal calibrate` with its defaults, 2 shared cores): 360 samples in 60 groups
# 8 s and 179 MB; 720 in 120, 24 s and 240 MB; 1440 in 120, 34 s and 251 MB; 1800 in 6, 4 s
# and 190 MB. Seconds ~ 5 + 2.9e-8 m n^2 + 1.5e-7 n^3 (the solver's SVDs, m rows, n columns);
# memory ~ 150 MB + 128 bytes per Jacobian entry (its weighted and scaled copies).
COINCIDENCE_SECONDS = (5.0, 2.9e-8, 1.5e-7)
COINCIDENCE_BYTES_PER_ENTRY = 128
MINUTES = 10.0  # default bound of a computation's estimated time (RELCAL_MAX_MINUTES)


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:,.0f} minutes"
    return f"{seconds / 3600:,.0f} hours"


def time_limit() -> float:
    """The seconds a computation may plan for: ``RELCAL_MAX_MINUTES`` (default 10) x 60."""
    return _env_number("RELCAL_MAX_MINUTES", MINUTES) * 60.0


def coincidence_cost(
    n_samples: int, n_groups: int, n_distances: int, n_params: int
) -> tuple[float, float]:
    """Estimated ``(bytes, seconds)`` of a calibration of coincidence samples: ``n_params``
    parameters of the robot (its largest candidate model), the tool point and ``n_groups``
    group points (see the measurements above)."""
    rows = 3.0 * n_samples + n_distances
    cols = float(n_params + 3 + 3 * n_groups)
    a, b, c = COINCIDENCE_SECONDS
    return (
        BASE_BYTES + COINCIDENCE_BYTES_PER_ENTRY * rows * cols,
        a + b * rows * cols**2 + c * cols**3,
    )


def check_coincidence_size(
    n_samples: int, n_groups: int, n_distances: int, n_params: int, where: str
) -> None:
    """Refuse coincidence data whose calibration would need more memory or time than the
    limits (``RELCAL_MAX_MEMORY_MB``, ``RELCAL_MAX_MINUTES``), before any work, with the
    estimate, the cause (the points of many groups are as many unknowns) and the remedies."""
    need, seconds = coincidence_cost(n_samples, n_groups, n_distances, n_params)
    limit, allowed = memory_limit(), time_limit()
    if need <= limit and seconds <= allowed:
        return
    what = (
        f"{where}: {n_samples:,} coincidence samples in {n_groups:,} groups ({3 * n_groups:,} "
        f"unknown group coordinates besides {n_params + 3} parameters of the robot and tool "
        "point, all in one dense fit)"
    )
    remedy = (
        "calibrate fewer placements at a time (a placement's groups share nothing with the "
        "others' but the robot), or fewer samples per group"
    )
    if need > limit:
        check_memory(need, what, remedy + "; or raise RELCAL_MAX_MEMORY_MB if the machine has it")
    raise RelcalError(
        f"{what} would take about {_duration(seconds)} (estimated from measured runs), "
        f"above the limit of {allowed / 60:g} minutes (RELCAL_MAX_MINUTES); {remedy}; or raise "
        "RELCAL_MAX_MINUTES to wait for it"
    )
