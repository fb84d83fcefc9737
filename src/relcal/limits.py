"""Bounds on what relcal reads and allocates, each checked before the work with a message that
names the input, the size found, the limit, and how to go on.

- **Input files** (:func:`check_input_size`): a file larger than the cap of its kind is refused
  before a byte is read. The caps are generous (a calibration's CSV of 200 MB holds millions of
  samples) and each can be raised with an environment variable, ``RELCAL_MAX_<KIND>_MB``
  (``RELCAL_MAX_CSV_MB=500``).
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
    """Refuse ``path`` before reading it when it is larger than the cap of its ``kind``
    (a missing or unreadable file is left to the reader's own message)."""
    try:
        size = os.stat(path).st_size
    except OSError:
        return
    cap = input_cap(kind)
    if size > cap:
        raise RelcalError(
            f"{path}: {_megabytes(size)}, above the {_megabytes(cap)} limit for {kind} input "
            f"files (not read); a wrong file? If it is right, raise the limit with "
            f"RELCAL_MAX_{kind.upper()}_MB"
        )


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


def resolve_pairing(pairing: str, n_samples: int) -> str:
    """The pairing ``auto`` stands for: ``board``, each pose against ``W F(q) X`` with the world
    (board) transform ``W`` estimated, whatever the number of samples (the maximum-likelihood
    form of independent pose noise, one measurement per sample, invariant to the order of the
    samples: docs/explanation/relative-formulation.md); any other pairing is itself.
    ``n_samples`` is kept for callers that resolve by size."""
    if pairing != "auto":
        return pairing
    return "board"


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
