"""Optimal control on the crash model: identification (fit to data, crashnlp.optimize.identify)
and design (no data, crashnlp.optimize.design), profile intervals on a fit
(crashnlp.optimize.profile), and the plain Result of a solve (crashnlp.optimize.outcome).
crashnlp.optimize.pipeline runs them in order; the submodules are imported where they are used.
"""
