"""Figure helpers (matplotlib, Agg backend, PNG): writing a figure, covariance ellipses."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse  # noqa: E402

from ekf_localization.core.linalg import symmetrise  # noqa: E402

CHI2_2DOF_95 = 5.991464547107979  # 95% mass of a 2-D Gaussian inside the ellipse


def save_figure(fig, out_png: Path | str) -> Path:
    """Lay out, write the PNG (creating its folder) and close the figure."""
    fig.tight_layout()
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def covariance_ellipse(mean: np.ndarray, cov: np.ndarray, chi2: float = CHI2_2DOF_95, **kw) -> Ellipse:
    """The ``chi2`` confidence ellipse of a 2-D Gaussian (default 95%)."""
    vals, vecs = np.linalg.eigh(symmetrise(cov))
    vals = np.clip(vals, 0.0, None)
    angle = np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1]))
    w, h = 2.0 * np.sqrt(chi2 * vals[1]), 2.0 * np.sqrt(chi2 * vals[0])
    return Ellipse(xy=(float(mean[0]), float(mean[1])), width=w, height=h, angle=angle, **kw)
