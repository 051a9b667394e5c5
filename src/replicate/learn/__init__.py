"""How the buoys learn: MADDPG (``maddpg``: the update as it reads, which the training runs; ``run_stack``), one
shared actor for any fleet (``shared_maddpg``, ``symmetry``), the machinery both trainings share (``loop``: the
replay memory of ``replay``, the update clock, the schedules of ``schedules``, the kept actor), the trainers
(``train``: one region; ``general_train``: any lake), the worlds of training (``training_worlds``), a run's record
(``runs``) and a training process's settings (``process``), the exported policy's modules (``policy``), the
arithmetic fingerprint (``fingerprint``) and the reduced-episode regression of reward curves (``regression``).
Imports ``world`` and ``core``."""
