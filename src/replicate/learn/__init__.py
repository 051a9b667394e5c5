"""How the buoys learn: MADDPG (``maddpg``, ``run_stack``), replay memories (``replay``), schedules of noise and
learning rate (``schedules``), a run's record (``runs``) and a training process's settings (``process``), one shared
actor for any fleet (``shared_maddpg``, ``symmetry``), the trainers (``train``: one region; ``general_train``: any
lake), the worlds of training (``training_worlds``), the exported policy's modules (``policy``), the arithmetic
fingerprint (``fingerprint``) and the reduced-episode regression of reward curves (``regression``). Imports
``world`` and ``core``."""
