"""SUMO as a second simulator: the left turn on Eclipse SUMO (through ``libsumo``), with the
same task, switching logics and policies as on the embedded simulator. Optional: install the
``safeswitch[sumo]`` extra.

* :mod:`safeswitch.sumo.network` — the intersection as a SUMO network, generated with
  ``netconvert`` from the same geometry;
* :mod:`safeswitch.sumo.plant` — one SUMO simulation (``libsumo``: one per process);
* :mod:`safeswitch.sumo.task` — the left-turn task with SUMO driving the other vehicles and
  the environments ``safeswitch/LeftTurnSumo-v0`` and :func:`make_sumo_vec_env` (worker
  processes).
"""
