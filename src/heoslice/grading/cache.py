"""What one graded layer leaves to the next: a typed cache, kept by the caller from layer to layer.

Consecutive layers of an extruded part have the same rings' edges, value for value
(:func:`heoslice.grading.edges.ring_geometry`). A family whose edges are the last layer's
takes its field from there; a family measured afresh takes what was measured of its ring
sets that stayed (edge trees, distances between ring sets, lattice passes); a layer whose
fields and solid bits are all the last layer's takes its labels; and a layer whose label
bases, fractions and mixes are the last one's takes its choice table. Everything held is a
pure function of its key, so a cache never changes what a layer renders, only how fast.
One cache serves one grid and one grading spec.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(slots=True)
class RingMemo:
    """What was measured of ring sets, by their keys: ``before`` the last layer's, ``now`` this layer's
    (edge trees by RingSet key, distances between two sets, lattice passes by key and lattice)."""

    before: dict = field(default_factory=dict)
    now: dict = field(default_factory=dict)

    def recall(self, key, make):
        """The value kept for ``key`` by the last layer or this one, else ``make()``; kept for the next layer."""
        value = self.before.get(key)
        if value is None:
            value = self.now.get(key)
        if value is None:
            value = make()
        self.now[key] = value
        return value

    def earlier(self, key):
        """The value the last layer kept for ``key``, or None."""
        return self.before.get(key)

    def keep(self, key, value) -> None:
        """Keep ``value`` for the next layer."""
        self.now[key] = value


@dataclass(frozen=True, slots=True)
class PaintedLabels:
    """A layer's labels painted from fields alone: the family keys, the packed solid bits, the label array."""

    keys: list
    packed: np.ndarray
    label: np.ndarray


@dataclass(frozen=True, slots=True)
class ChoiceTable:
    """A layer's choice table (:func:`heoslice.grading.droplets.choice_table`) and what it was made from."""

    key: tuple
    table: np.ndarray

    def matches(self, key: tuple) -> bool:
        """Whether ``key`` (arrays) equals the one this table was made from, array for array."""
        return len(self.key) == len(key) and all(map(np.array_equal, self.key, key))


@dataclass(slots=True)
class GradingCache:
    """The last graded layer's fields (by family key), ring measurements, painted labels, choice table and
    family keys."""

    fields: dict = field(default_factory=dict)
    rings: dict = field(default_factory=dict)
    painted: PaintedLabels | None = None
    choices: ChoiceTable | None = None
    keys: list = field(default_factory=list)

    def fields_for(self, keys: list) -> dict:
        """The last layer's fields, those whose keys this layer has not dropped (before its fields are made)."""
        wanted = set(keys)
        self.fields = {key: value for key, value in self.fields.items() if key in wanted}
        return self.fields

    def take_painted(self, keys: list) -> PaintedLabels | None:
        """The last layer's painted labels when they were painted from fields with these keys (else None);
        taken out, so that labels from other fields are freed before this layer's are painted."""
        painted, self.painted = self.painted, None
        return painted if painted is not None and painted.keys == keys else None

    def ring_memo(self) -> RingMemo:
        """A memo of ring measurements reading the last layer's."""
        return RingMemo(before=self.rings)

    def repeats(self, key) -> bool:
        """Whether the last layer had a family of this key (its field kept or not): the sign of an extruded
        stretch, whose next layer will likely have it too."""
        return key is not None and key in self.keys

    def keep_layer(self, keys: list, fields: tuple, memo: RingMemo, keep_first: bool = True) -> None:
        """Keep this layer's family keys, its fields (those with a key; the first only when ``keep_first``:
        the layer's labels were painted over its index) and ring measurements for the next layer."""
        self.keys = list(keys)
        self.fields = {key: value for number, (key, value) in enumerate(zip(keys, fields))
                       if key is not None and (number or keep_first)}
        self.rings = memo.now
