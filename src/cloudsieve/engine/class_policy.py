"""Class policies of the eliminate rule (``keep_class``, ``class_ratio``): :class:`ClassPolicy`.

Each point falls in one *group* by its LAS classification: -1 kept whole, 0
following ``ratio``/``count``, one per class of ``class_ratio`` below 1;
each group's target is exact (docs/architecture.md, "Class policies"). The
class counts and the rows of ``partition/class`` come from a task per chunk.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core._validation import ratio_count
from ..errors import InputFormatError

__all__ = ["WHOLE", "ClassPolicy", "check_classified", "class_codes", "class_counts_task", "class_rows_task",
           "run_class_counts", "run_class_rows"]

#: the group of the points kept whole
WHOLE = -1
#: the attribute the policies read
CLASSIFICATION = "classification"


@dataclass(frozen=True)
class ClassPolicy:
    """The groups of a run: *lookup* (256,) int8, each class code's group; *ratios*: group g >= 1's ratio;
    *ratio*/*count*: group 0's target, as the run's."""

    lookup: np.ndarray
    ratios: tuple
    ratio: float | None
    count: int | None

    @classmethod
    def from_options(cls, opts: dict) -> "ClassPolicy | None":
        """The policy of validated *opts*, None when neither ``keep_class`` nor ``class_ratio`` is given."""
        keep, pairs = opts.get("keep_class"), opts.get("class_ratio")
        if keep is None and pairs is None:
            return None
        lookup = np.zeros(256, dtype=np.int8)
        lookup[list(keep or ())] = WHOLE
        ratios = []
        for code, ratio in pairs or ():
            if ratio >= 1.0:
                lookup[int(code)] = WHOLE
            else:
                ratios.append(float(ratio))
                lookup[int(code)] = len(ratios)
        return cls(lookup, tuple(ratios), opts["ratio"], opts["count"])

    @property
    def groups(self) -> int:
        """Groups eliminated (the whole classes are none of them)."""
        return 1 + len(self.ratios)

    def group_points(self, counts: np.ndarray) -> np.ndarray:
        """Points (G,) of each group, from the class counts (256,)."""
        g = self.lookup.astype(np.int64)
        return np.bincount(g[g >= 0], weights=np.asarray(counts)[g >= 0], minlength=self.groups).astype(np.int64)

    def targets(self, counts: np.ndarray) -> np.ndarray:
        """Each group's exact kept count (G,) from the class counts (256,)."""
        n = self.group_points(counts)
        first = ratio_count(self.ratio, int(n[0])) if self.ratio is not None else min(int(self.count), int(n[0]))
        return np.array([first, *(ratio_count(r, int(m)) for r, m in zip(self.ratios, n[1:]))], dtype=np.int64)

    def asked(self, counts: np.ndarray) -> int:
        """Points the policy keeps in all: the whole classes' and each group's target."""
        whole = int(np.asarray(counts)[self.lookup == WHOLE].sum())
        return whole + int(self.targets(counts).sum())

    def describe(self, code: int) -> str:
        """The policy of class *code* in words: ``whole``, ``ratio 0.1`` or ``ratio 0.5 (rest)``."""
        return self.words(int(self.lookup[code]))

    def words(self, g: int) -> str:
        """The policy of group *g* in words (:meth:`describe`)."""
        if g == WHOLE:
            return "whole"
        if g > 0:
            return f"ratio {self.ratios[g - 1]:g}"
        return f"ratio {self.ratio:g} (rest)" if self.ratio is not None else f"count {self.count} (rest)"

    def report(self, counts: np.ndarray, kept: np.ndarray) -> dict:
        """The summary's ``classes``: ``asked`` (points the policy keeps in all), ``policies`` (per policy: its
        ``classes`` present, ``points_in``, ``target``, ``kept``) and ``classes`` (per class present:
        ``class``, ``policy``, ``points_in``, ``kept``, ``ratio`` achieved), from the class counts (256,)
        of the input and of the kept points."""
        counts, kept = np.asarray(counts, dtype=np.int64), np.asarray(kept, dtype=np.int64)
        present = np.flatnonzero(counts)
        targets = self.targets(counts)
        policies = []
        for g in (*range(self.groups), WHOLE):
            codes = [int(c) for c in present if self.lookup[c] == g]
            if codes or g == 0:
                inside = int(counts[codes].sum())
                policies.append({"policy": self.words(g), "classes": codes, "points_in": inside,
                    "target": inside if g == WHOLE else int(targets[g]), "kept": int(kept[codes].sum())})
        return {"asked": self.asked(counts), "policies": policies,
                "classes": [{"class": int(c), "policy": self.describe(int(c)), "points_in": int(counts[c]),
                             "kept": int(kept[c]), "ratio": float(kept[c]) / float(counts[c])} for c in present]}


def check_classified(sources: list[str], store: bool) -> None:
    """Refuse (InputFormatError naming the file) a source without a classification, before any work."""
    from ..io import detect_format, open_reader

    if store:
        from ..store import PointStore

        if CLASSIFICATION not in PointStore.open(sources[0]):
            raise InputFormatError(f"{sources[0]}: the point store has no classification, which keep_class and "
                                   "class_ratio need")
        return
    for path in sources:
        if detect_format(path) in ("las", "laz", "copc"):
            continue  # every LAS point format has one
        with open_reader(path) as reader:
            if CLASSIFICATION not in reader.dtypes:
                raise InputFormatError(f"{path}: no classification attribute, which keep_class and class_ratio "
                                       "need (LAS/LAZ/COPC have one)")


def class_codes(values, where: str) -> np.ndarray:
    """*values* as class codes (n,) uint8; InputFormatError naming *where* for a value that is not one of 0..255
    (a PLY or store attribute of another type)."""
    v = np.asarray(values)
    if v.size and (v.dtype.kind not in "iub" or int(v.min()) < 0 or int(v.max()) > 255):
        raise InputFormatError(f"{where}: its classification holds values that are not class codes 0..255 "
                               f"({v.dtype}, {v.min()} to {v.max()})")
    return v.astype(np.uint8, copy=False)


def class_counts_task(store_path: str, start: int, stop: int, mask: str | None) -> np.ndarray:
    """Task: points (256,) int64 of each class among ``[start, stop)``, only those of *mask* when given."""
    from ..store import PointStore

    st = PointStore.open(store_path)
    codes = class_codes(st.array(CLASSIFICATION)[start:stop], store_path)
    if mask is not None:
        codes = codes[np.asarray(st.group[mask][start:stop], dtype=bool)]
    return np.bincount(codes.astype(np.int64), minlength=256)


def run_class_counts(store, runner, mask: str | None = None) -> np.ndarray:
    """Points (256,) of each class of *store* (of *mask*'s points when given), a task per chunk."""
    n, step = store.count, store.chunk_size
    args = [(store.path, s, min(s + step, n), mask) for s in range(0, n, step)]
    parts = runner(class_counts_task, args, "classes")
    return np.sum(parts, axis=0, dtype=np.int64) if parts else np.zeros(256, dtype=np.int64)


def class_rows_task(store_path: str, chunk: int, start: int, stop: int) -> None:
    """Task: ``partition/class[chunk]``, the classes of ``[start, stop)`` in the order of ``partition/xyz[chunk]``
    (by cell, stable); a chunk's own row."""
    from ..store import PointStore

    st = PointStore.open(store_path, "r+")
    labels = np.asarray(st.group["partition/cell"][start:stop])
    codes = class_codes(st.array(CLASSIFICATION)[start:stop], store_path)
    st.group["partition/class"][chunk, : stop - start] = codes[np.argsort(labels, kind="stable")]


def run_class_rows(store, runner) -> None:
    """``partition/class`` (n_chunks, R) uint8 beside ``partition/xyz``, a task per chunk."""
    n, step = store.count, store.chunk_size
    xyz = store.group["partition/xyz"]
    store.delete_array("partition/class")
    store.create_array("partition/class", shape=xyz.shape[:2], dtype="uint8", chunks=(1, xyz.shape[1]),
                       fill_value=0)
    runner(class_rows_task, [(store.path, c, s, min(s + step, n)) for c, s in enumerate(range(0, n, step))],
           "partition: classes")
