"""The estimation core under calibration and discovery: one likelihood, priors, nuisances, intervals.

- ``unknowns``: a model as a value (base parameters + effects) and what a fit may move, with bounds
  and priors (Table I with a stated tolerance, or the rig's declared values);
- ``problem``: recordings of one rig as targets (model -> residuals, noise) and the whitened
  residual the fit minimises;
- ``fit``: ``least_squares`` with priors as extra rows; ``FitResult`` with covariance, AIC/BIC
  counting every free parameter, and profile-likelihood intervals;
- the nuisances and the noise: ``start`` (a recording's start as a value), ``initial_state`` (its
  estimate for a given plant: superposed simulations, linear least squares), ``noise`` (each
  signal's noise floor from the recording itself, no model needed).
"""

from pipeline.estimate.fit import FitResult, autocorrelation_time, fit
from pipeline.estimate.problem import Problem, Target
from pipeline.estimate.unknowns import SPRINGS, Model, Prior, Unknown, effect_unknowns

__all__ = ["FitResult", "Model", "Prior", "Problem", "SPRINGS", "Target", "Unknown", "autocorrelation_time",
           "effect_unknowns", "fit"]
