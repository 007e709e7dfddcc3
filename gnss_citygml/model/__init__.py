"""Building-height estimators: 4PL-B and the paper's baselines."""

from .classifier import SignalClassifier
from .estimate import HEIGHTS_COLUMNS, METHODS, estimate_heights
from .fourpl import FourPLFit, fit_4pl, log_likelihood, logistic4

__all__ = [
    "HEIGHTS_COLUMNS",
    "METHODS",
    "FourPLFit",
    "SignalClassifier",
    "estimate_heights",
    "fit_4pl",
    "log_likelihood",
    "logistic4",
]
