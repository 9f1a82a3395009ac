"""A run's products as its tasks need them: a typed part of the run's config.

:class:`ProductSettings` is built once per run from the layers asked for and
the registry: which layers to compute (with the ones they need), which points
the products read (the union of their selections), which attributes those
points carry past the reader, and the DSM's maximum edge.  It is small and
picklable: it crosses to the route and tile tasks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .declare import Attribute, Returns, Selection
from .registry import PRODUCTS, product

__all__ = ["ProductSettings", "DSM_EDGE_SPACINGS", "layers_needed"]

DSM_EDGE_SPACINGS = 5.0
"""The DSM's default maximum edge, in the survey's mean point spacing (every
return counted): first returns lie about 1.2-1.5 spacings apart, so the
TIN bridges the gaps between them on roofs and crowns, and leaves open the
wider voids of water and occlusions."""


DSM_CELLS_PER_EDGE = 4.0
"""The DSM keeps the highest first return of cells at most its maximum edge
over this wide (the grid's cells when they are finer)."""


def layers_needed(layers: tuple[str, ...]) -> tuple[str, ...]:
    """``layers`` and every layer they are computed from, in registry order."""
    wanted = set(layers)
    pending = list(layers)
    while pending:
        for dep in product(pending.pop()).needs:
            if dep not in wanted:
                wanted.add(dep)
                pending.append(dep)
    return tuple(p.name for p in PRODUCTS if p.name in wanted)


@dataclass(frozen=True)
class ProductSettings:
    """The products of one run, as its tasks read them."""

    layers: tuple[str, ...]
    """The layers the store holds (elevation first)."""
    computed: tuple[str, ...]
    """Those and the layers they need, in registry order."""
    dtm: Selection
    """The DTM's points: the run's classes (after a fallback) and returns."""
    reads: Selection | None
    """The union of the point selections of the computed products (None: none reads points)."""
    columns: tuple[str, ...]
    """The attributes the product points carry (beyond x, y, z), in order."""
    dsm_max_edge: float = math.inf
    keep_withheld: bool = False
    classified: bool = False
    """The DTM's points are the ground stage's (:mod:`pipeline.meshing.ground`), not a class of the files:
    :attr:`dtm` selects the points it classified, and the tiles read its ground points for the DTM's."""
    cell: float = 0.0
    """The side of the grid's cells."""

    @classmethod
    def for_run(cls, layers: tuple[str, ...], classes: tuple[int, ...] | None, returns: str,
                dsm_max_edge: float | None = None, keep_withheld: bool = False,
                classified: bool = False, cell: float = 0.0) -> ProductSettings:
        computed = layers_needed(layers)
        dtm = Selection(None if classes is None else frozenset(classes), Returns.parse(returns))
        partial = cls(tuple(layers), computed, dtm, None, (), math.inf if dsm_max_edge is None else dsm_max_edge,
                      keep_withheld, classified, cell)
        selections = [s for s in (p.points(partial) for p in map(product, computed) if p.points is not None)
                      if s is not None]
        if not selections:
            return partial
        reads = selections[0]
        for s in selections[1:]:
            reads = reads.union(s)
        wanted: list[Attribute] = []
        for name in computed:
            p = product(name)
            selection = None if p.points is None else p.points(partial)
            if selection is not None:
                wanted.extend(selection.attributes_to_split(reads))
            wanted.extend(p.attributes)
        columns = tuple(a.value for a in Attribute if a in wanted)
        return cls(tuple(layers), computed, dtm, reads, columns, partial.dsm_max_edge, keep_withheld, classified, cell)

    @property
    def reads_points(self) -> bool:
        """Whether some product reads points (so the route stage spills them)."""
        return self.reads is not None

    @property
    def margin(self) -> float:
        """How far beyond a tile's box the products need every point of their
        selections (the DSM's: twice its maximum edge, which holds the
        circumcircle of every triangle it draws over the tile's cells, and
        one and a half of its cells, which hold the whole cell of each corner,
        whose highest return it is)."""
        return 2.0 * self.dsm_max_edge + 1.5 * self.dsm_cell if "dsm" in self.computed else 0.0

    @property
    def dsm_cell(self) -> float:
        """The side of the cells whose highest first return the DSM keeps: the
        grid's, or :data:`DSM_CELLS_PER_EDGE` of them along its maximum edge
        when the grid's cells are coarser (the returns kept lie about a cell
        apart, and the TIN must still join them)."""
        return min(self.cell, self.dsm_max_edge / DSM_CELLS_PER_EDGE)

    def spill_buffer(self, buffer: float) -> float:
        """The buffer of the products' spill files, for tiles of ``buffer``: at
        least :attr:`margin`, so that any buffer gives the products they need."""
        return max(buffer, self.margin)

    def reading(self) -> tuple[Selection, tuple[str, ...]]:
        """What the reader keeps (the DTM's points and the products') and the
        attributes it decodes for them: the products' columns, and those that
        tell the DTM's points from the products' ones."""
        if self.reads is None:
            return self.dtm, ()
        union = self.dtm.union(self.reads)
        wanted = set(self.columns) | {a.value for a in self.dtm.attributes_to_split(union)}
        wanted |= {a.value for a in self.reads.attributes_to_split(union)}
        return union, tuple(a.value for a in Attribute if a.value in wanted)
