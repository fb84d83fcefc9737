"""The samples in an order of their own: what a calibration computes depends on the data alone.

A table's rows come in whatever order a recording or a spreadsheet left them, and a sample's id
is a label. Everything downstream that draws at random (the held-out split, the folds, the
bootstraps) or pairs samples works on sample indices, so the samples are first put in an order
that depends on their content alone: joint values, then what was measured (the pose, the group
of a coincidence sample, the image's bytes), compared exactly. Reordering the rows of a file or
renaming its ids then changes nothing but the labels.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np

from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements


def _digest(path: Path) -> int:
    """An integer from the first 8 bytes of the BLAKE2 digest of a file's bytes."""
    digest = hashlib.blake2b(digest_size=8)
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return int.from_bytes(digest.digest(), "big") >> 1  # fits an int64


def canonical_order(dataset: Dataset) -> np.ndarray:
    """The permutation ``(N,)`` that puts ``dataset``'s samples in their content's order.

    Keys, most significant first: the joint values (exact floats, joint by joint), the measured
    pose (its 16 numbers), the group name of a coincidence sample, and, for samples that tie on
    all of these, a digest of the image file. Samples that tie on everything are the same
    sample; their order among themselves is their ids' (which then label identical data).
    """
    keys: list[np.ndarray] = []  # np.lexsort: the last key is the most significant
    n = len(dataset.ids)
    keys.append(np.unique(np.asarray(dataset.ids, dtype=object), return_inverse=True)[1])
    if dataset.groups is not None:
        keys.append(np.unique(np.asarray(dataset.groups, dtype=object), return_inverse=True)[1])
    if dataset.poses is not None:
        flat = np.asarray(dataset.poses, dtype=float).reshape(n, -1)
        keys.extend(flat[:, k] for k in reversed(range(flat.shape[1])))
    q = np.asarray(dataset.q, dtype=float)
    keys.extend(q[:, k] for k in reversed(range(q.shape[1])))
    order = np.lexsort(keys) if keys else np.arange(n)
    if dataset.images is not None:
        order = _break_image_ties(dataset, order)
    return order


def _break_image_ties(dataset: Dataset, order: np.ndarray) -> np.ndarray:
    """``order`` with runs of samples of equal joints ordered by their images' bytes."""
    q = np.asarray(dataset.q)[order]
    same = np.all(q[1:] == q[:-1], axis=1)
    if not same.any():
        return order
    out = order.copy()
    start = 0
    for k in range(1, len(order) + 1):
        if k == len(order) or not same[k - 1]:
            if k - start > 1:
                run = order[start:k]
                digests = [_digest(dataset.images[i]) for i in run]
                ids = [dataset.ids[i] for i in run]
                out[start:k] = run[np.lexsort((ids, digests))]
            start = k
    return out


def take(dataset: Dataset, index: np.ndarray) -> Dataset:
    """``dataset`` with the samples ``index`` (in that order): ids, joints, images, poses,
    groups."""
    index = np.asarray(index, dtype=int)
    return replace(
        dataset,
        ids=tuple(dataset.ids[i] for i in index),
        q=np.asarray(dataset.q)[index],
        images=None if dataset.images is None else tuple(dataset.images[i] for i in index),
        poses=None if dataset.poses is None else np.asarray(dataset.poses)[index],
        groups=None if dataset.groups is None else tuple(dataset.groups[i] for i in index),
    )


def take_measurements(measurements: Measurements, index: np.ndarray) -> Measurements:
    """``measurements`` of the samples ``index`` (in that order)."""
    index = np.asarray(index, dtype=int)
    cov = measurements.covariance
    return replace(
        measurements,
        poses=measurements.poses[index],
        ok=measurements.ok[index],
        reasons=tuple(measurements.reasons[i] for i in index),
        rms_px=measurements.rms_px[index],
        covariance=None if cov is None else cov[index],
    )


def in_canonical_order(
    dataset: Dataset, measurements: Measurements | None = None
) -> tuple[Dataset, Measurements | None]:
    """``dataset`` (and its ``measurements``, when given) with the samples in
    :func:`canonical_order`; unchanged objects when they already are."""
    order = canonical_order(dataset)
    if np.array_equal(order, np.arange(len(order))):
        return dataset, measurements
    return take(dataset, order), None if measurements is None else take_measurements(
        measurements, order
    )


def sample_digests(q: np.ndarray, poses: np.ndarray | None = None, groups=None) -> list[str]:
    """A short digest per sample of its joints ``(N, n)`` and what it measured (poses
    ``(N, 4, 4)``, coincidence groups), rounded to 12 decimals: equal for a sample read again
    from the same file, different for a new measurement of the same configuration."""
    q = np.round(np.asarray(q, dtype=float), 12)
    flat = (
        None if poses is None else np.round(np.asarray(poses, dtype=float), 12).reshape(len(q), -1)
    )
    out = []
    for k in range(len(q)):
        digest = hashlib.blake2b(q[k].tobytes(), digest_size=8)
        if flat is not None:
            digest.update(flat[k].tobytes())
        if groups is not None:
            digest.update(str(groups[k]).encode())
        out.append(digest.hexdigest())
    return out


def _natural_key(sid: str) -> tuple:
    """``s10`` after ``s9``: digits compared as numbers, the rest as text."""
    import re

    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", sid))


def natural(ids) -> list[str]:
    """Sample ids sorted as a person lists them (``2`` before ``10``): how outputs list samples,
    whatever the order the calibration kept them in."""
    return sorted(ids, key=_natural_key)
