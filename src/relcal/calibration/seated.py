"""What seated samples share (the coincidence formulation's data): the group each sample was
seated in, the groups' point guesses, the tool point guess and the known distances between groups.

Held apart from :mod:`relcal.calibration.coincidence` (the formulation itself, which registers
its residuals with :mod:`relcal.calibration.measurement`) so that a
:class:`~relcal.calibration.measurement.Problem` can carry these data without the measurement
layer importing the formulation that builds on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

SEATING = 1e-4  # default standard deviation of one sample's point (m): 0.1 mm


def placement_of(group: str) -> str:
    """The placement a group belongs to: its name up to the last ``/`` (``""`` without one)."""
    return group.rpartition("/")[0]


@dataclass(frozen=True)
class Coincidence:
    """What coincidence samples share: per sample its group, per group its name and point guess,
    the tool point guess and the known distances.

    ``index`` ``(N,)`` group of each sample (into ``names``); ``points`` ``(G, 3)`` guesses of
    the group points (base frame, m); ``tool_point`` ``(3,)`` guess of the tool point (tip frame,
    m); ``pairs`` ``(D, 2)`` groups of each known distance, ``lengths`` ``(D,)`` and ``stds``
    ``(D,)`` the distances and their standard deviations (m); ``seating`` the standard deviation
    of one sample's point (m) that weighs the distance rows against the sample rows when the
    problem is not weighted.
    """

    index: np.ndarray
    names: tuple[str, ...]
    points: np.ndarray
    tool_point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=int))
    lengths: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stds: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seating: float = SEATING

    def __post_init__(self) -> None:
        object.__setattr__(self, "index", np.asarray(self.index, dtype=int))
        object.__setattr__(self, "points", np.asarray(self.points, dtype=float).reshape(-1, 3))
        object.__setattr__(self, "tool_point", np.asarray(self.tool_point, dtype=float))
        object.__setattr__(self, "pairs", np.asarray(self.pairs, dtype=int).reshape(-1, 2))
        object.__setattr__(self, "lengths", np.asarray(self.lengths, dtype=float).reshape(-1))
        object.__setattr__(self, "stds", np.asarray(self.stds, dtype=float).reshape(-1))
        if len(self.points) != len(self.names):
            raise ValueError(f"{len(self.points)} point guesses for {len(self.names)} groups")
        if not (len(self.pairs) == len(self.lengths) == len(self.stds)):
            raise ValueError("pairs, lengths and stds of the distances differ in length")
        if np.any(self.stds <= 0):
            raise ValueError("the standard deviation of a known distance must be positive")

    @property
    def n_groups(self) -> int:
        return len(self.names)

    @property
    def placements(self) -> tuple[str, ...]:
        """The placement of each group (:func:`placement_of`)."""
        return tuple(placement_of(n) for n in self.names)

    def placement_names(self) -> tuple[str, ...]:
        """The placements, in the order their groups first appear."""
        return tuple(dict.fromkeys(self.placements))

    def samples_of(self, placements: str | tuple[str, ...] | list[str]) -> np.ndarray:
        """Indices of the samples whose groups belong to ``placements``."""
        wanted = {placements} if isinstance(placements, str) else set(placements)
        keep = np.array([p in wanted for p in self.placements], dtype=bool)
        return np.flatnonzero(keep[self.index]) if len(self.index) else np.zeros(0, int)

    def restricted(self, samples: np.ndarray) -> Coincidence:
        """These samples only: the groups without samples left out with their distances, the
        others re-indexed in their order."""
        index = self.index[np.asarray(samples, dtype=int)]
        kept = np.unique(index)
        new = np.full(self.n_groups, -1)
        new[kept] = np.arange(len(kept))
        both = np.all(new[self.pairs] >= 0, axis=1) if len(self.pairs) else np.zeros(0, bool)
        return replace(
            self,
            index=new[index],
            names=tuple(self.names[g] for g in kept),
            points=self.points[kept],
            pairs=new[self.pairs[both]],
            lengths=self.lengths[both],
            stds=self.stds[both],
        )

    def without_distances(self) -> Coincidence:
        return replace(self, pairs=np.zeros((0, 2), int), lengths=np.zeros(0), stds=np.zeros(0))
