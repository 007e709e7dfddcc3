"""Building-height estimators: 4PL-B and the paper's baselines.

:func:`~gnss_citygml.model.estimate.estimate_heights` runs any of them on an intersections
table. This package imports none of its modules (scipy is slow to load): it only names the
methods, so that the command line can offer them without loading the estimators.
"""

__all__ = ["METHODS"]

#: The estimators, by the names the paper uses.
METHODS = ("4PL-B", "4PL", "hinge", "bayes")
