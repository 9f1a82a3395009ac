"""experiments: the papers' experiments, run over meshcore (no pipeline).

``combined_mesh`` is the error experiment of "Surface design based upon a
combined mesh" (section 3: Tables 1-3, Figure 2), which ``terrain experiment``
runs.  It prints tables and writes figures, so it lives here rather than in
meshcore, whose kernels do no I/O.
"""

from __future__ import annotations

from .errors import ExperimentError, ExperimentOutputError, ExperimentParameterError

__all__ = ["ExperimentError", "ExperimentParameterError", "ExperimentOutputError"]
