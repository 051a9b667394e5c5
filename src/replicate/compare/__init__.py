"""What a result is read against: the baselines (naive swarming, Lloyd, geodesic Lloyd), the best layout,
metrics and statistics, the baselines' tuning, the evaluation of runs and policies, the general policy's suite
and the yardstick that decides between two versions of a training. Imports ``learn``, ``world`` and ``core``."""
