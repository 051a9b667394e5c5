"""The pipeline's stages, as the notebooks of ``dvc.yaml`` call them: the training matrix (``matrix``), the
evaluation of every run and baseline into ``metrics/summary.json`` (``evaluation``), the general policy's seeds,
its suite and the yardstick's standing baseline (``general``), the figures (``figures``) and ``REPORT.md``
(``report``). The library below them (world, learning, baselines, statistics) knows nothing of
stages."""
