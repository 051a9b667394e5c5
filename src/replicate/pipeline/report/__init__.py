"""``REPORT.md``, generated from ``metrics/summary.json``: the paper's claims (SPEC §10), each judged by a rule
fixed in ``params.yaml`` ``report`` before the numbers and printed beside its verdict with the verdict under the
rule's margins and tolerances halved and doubled; the headline comparisons with intervals of their differences
and probabilities of improvement; the targets of ``tuned``; the search budgets; the robustness table; the
ablation; the coverage tables, the timings and the figures. Nothing in it is typed by hand: ``write`` fills the
template ``REPORT.md.j2`` with the rows of ``claims``, ``general`` and ``tables``."""
