"""Chi-square quantiles, as ``scipy.stats.chi2`` computes them, without its import.

``import scipy.stats`` costs a process about 0.8 s (its distributions module), and
every 2-D run reached it through one quantile (the doubt that compares the
residuals with the stated noise): a third of a short run's time, in every one of
the suite's command-line tests. These call the same ``scipy.special`` routines
``scipy.stats.chi2`` calls (``_ppf``: ``2 * gammaincinv(dof / 2, p)``; ``_isf``:
``chdtri(dof, alpha)``), so the values are the same bits
(``tests/slamcore/test_chi2.py`` checks them against ``scipy.stats``).
"""

from __future__ import annotations

__all__ = ["ppf", "isf", "median"]


def ppf(p: float, dof: float) -> float:
    """The quantile ``x`` with ``P(chi2(dof) <= x) = p`` (``scipy.stats.chi2.ppf``)."""
    from scipy.special import gammaincinv  # here: scipy.special costs 0.3 s at import

    return 2.0 * float(gammaincinv(dof / 2, p))


def isf(alpha: float, dof: float) -> float:
    """The quantile ``x`` with ``P(chi2(dof) > x) = alpha`` (``scipy.stats.chi2.isf``)."""
    from scipy.special import chdtri

    return float(chdtri(dof, alpha))


def median(dof: float) -> float:
    """The median of ``chi2(dof)`` (``scipy.stats.chi2.median``)."""
    return ppf(0.5, dof)
