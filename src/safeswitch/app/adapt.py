"""``safeswitch adapt``: learning after deployment — the policy keeps learning from what it
meets in the field while the switching logic stays authoritative (the paper leaves this out,
its Remark 1).

The trained policy is deployed episode after episode on a distribution described by
``--set env.KEY=VALUE`` (a *shift*: a faster oncoming car, other starting speeds, …) under a
switching logic (``certified`` by default: nothing the policy learns can make it collide while
the logic's assumptions hold). Every episode it drives is experience: PPO continues from the
policy's own weights and observation statistics, with the reward it was trained
with (``R_ADAS`` for each tick the safety action runs, and its constraints' costs at the
multipliers its training ended with), exploring with the noise its training ended with,
narrowing to a quarter of it by the last episode. What keeps it from forgetting, and from
deploying a worse policy:

* a trust region: the value function learns the shift first, the actor then moves at a
  sixteenth of the training rate in PPO's clipped steps, and the observation statistics stay
  frozen;
* rehearsal with an anchor: a quarter of the learner's environments replay scenarios of the
  original distribution (simulated, beside the deployed ones; not counted as deployed), and on
  their states the actor is fitted toward the original policy's actions after each update;
* selection: after each block the deterministic policy is evaluated on held-out scenarios of
  the shift and of the original distribution and ranked (:func:`selection_key`); the best so
  far — the frozen policy to begin with — is the one adapting hands back, and a block whose
  policy ranks below it is rolled back (unless ``rollback`` is off): learning goes on from the
  selected one (with the next rollout, not the rejected policy's), so a policy the held-out
  evaluation found worse is not deployed further;
* settling: while the selected policy meets every target on the held-out scenarios, learning
  pauses — the selected policy is deployed without exploration noise and nothing is updated —
  until a deployed block needs the safety action more often than :data:`SAFETY_BUDGET` (or
  fails), when learning resumes from it (unless ``settle`` is off). A policy that meets its
  targets is not changed further in the field.

Deployment runs in blocks of ``block`` episodes; after each, the block's deployed episodes
are summarised (``blocks``: ``episodes``, ``collisions``, ``failures``,
``safety_activation_episodes``, ``speeding_episodes``, ``mean_efficiency`` against the oracle on
the same scenarios, ``rolled_back``, ``settled``) together with the held-out evaluations
(``held_out``, ``held_out_original``), and a checkpoint is written whole: ``--resume``
continues after the last complete block (Ctrl-C leaves the last one). The adapted (selected)
policy is a run directory (``model.zip``, ``vecnormalize.pkl``, ``config.yaml``) that
``safeswitch evaluate --model`` accepts; it and the frozen one are evaluated on other unseen
scenarios of both distributions (``summary.json``: ``shifted``, ``original``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from safeswitch.app.evaluate import scene_settings
from safeswitch.io import (
    prepare_output_dir,
    write_json,
    write_policy_files,
    write_snapshot,
)
from safeswitch.progress import Progress

#: The actor's schedule while it adapts (docs/adapt.md): the value function alone for this
#: many steps, then the actor's rate rises to 3e-5 (a sixteenth of the training rate) over as
#: many. On the ``certified`` policy's ``ego-fast`` shift, 3,000 episodes: at the training's
#: own rate from the first step the held-out safety-action episodes went 199 → 344 of 500 (after
#: 2,000), at 1e-4 after the warm-up they went to 529 of 1,000 and the original distribution's
#: from 189 to 530; at 3e-5 199 → 191, the original's 86 → 88 and its efficiency within 0.01.
ACTOR_FROZEN_STEPS = 60_000
ACTOR_RAMP_STEPS = 60_000
ACTOR_LEARNING_RATE = 3e-5

#: The selection's targets (issue #40's): the share of episodes with a safety action, and how
#: far the original distribution's efficiency may fall (:func:`selection_key`).
SAFETY_BUDGET = 0.02
EFFICIENCY_TOLERANCE = 0.01

#: The share of the learner's environments that replay the policy's original scenarios by
#: default (see :func:`adapt`'s ``rehearsal``).
REHEARSAL = 0.25

#: The weight of the fit toward the original policy's actions on the rehearsing environments'
#: states (:meth:`~safeswitch.training.ppo.SwitchPPO.anchor_to`).
ANCHOR_WEIGHT = 1.0

#: The exploration noise at the last deployed episode, as a share of the first's (``adapt``'s
#: ``noise_decay``): the field's exploration narrows as the policy settles.
NOISE_DECAY = 0.25

#: The log standard deviation of the deployed actions while learning is paused (settled): a
#: noise of 2e-9, the deterministic policy in effect.
SETTLED_LOG_STD = -20.0


class AdaptError(ValueError):
    """An adaptation cannot run as asked; the message says why."""


def _evaluation(policy: Any, config: Any, traffic: Any, episodes: int, seed: int) -> dict[str, Any]:
    """The deterministic policy's summary on ``episodes`` scenarios of ``config`` (``seed``)."""
    from safeswitch.evaluation.evaluate import run_controller, summary_against_oracle
    from safeswitch.leftturn.make import build_task

    task = build_task(None, config, traffic=traffic)
    scenarios = task.scenario_set(seed, episodes)
    result, plan = run_controller(task, policy.as_policy(), scenarios, trace=False)
    return summary_against_oracle(result, plan, task.config.episode.horizon_s)


def _brief(summary: dict[str, Any]) -> dict[str, Any]:
    keys = (
        "episodes", "collisions", "failures", "safety_activation_episodes", "speeding_episodes",
        "cleared_episodes", "mean_efficiency", "max_speed_kmh", "comfort_violation_fraction",
    )  # fmt: skip
    return {k: summary.get(k) for k in keys}


def adapt(
    model: str | Path,
    out: str | Path,
    *,
    switching: str = "certified",
    settings: Sequence[str] = (),
    episodes: int = 10_000,
    block: int = 1_000,
    n_envs: int = 16,
    seed: int = 0,
    eval_episodes: int = 2_000,
    eval_seed: int = 1_000_003,
    noise: float | None = None,
    noise_decay: float | None = None,
    rehearsal: float | None = None,
    rollback: bool = True,
    settle: bool = True,
    resume: bool = False,
    progress: bool = False,
) -> dict[str, Any]:
    """Deploy ``model`` on the shift and let it keep learning (see the module docstring);
    returns ``summary.json``'s contents. ``noise``: the standard deviation of the exploration
    noise on the deployed actions (``None``: the size its training ended with); a smaller one
    meets the safety action less often in the field and learns from less variety.
    ``noise_decay``: the noise at the last deployed episode as a share of the first's
    (``None``: :data:`NOISE_DECAY`; the log standard deviation falls linearly with the
    episodes deployed; 1: constant).
    ``rollback``: after a block whose policy ranks below the selected one
    (:func:`selection_key`), learning goes on from the selected policy instead — a policy the
    held-out evaluation found worse is not deployed further. On by default: on ``north-slow``
    (docs/adapt.md) a policy learning on without it drifted back onto the filter late in the
    run (35 and 70 of the last block's 1,000 episodes on two seeds of three; 22 and 7 with
    it). ``rehearsal``: the share of the learner's environments (``None``:
    :data:`REHEARSAL`; rounded, at least one if not 0) that replay scenarios of the policy's
    original distribution while it adapts — simulated episodes beside the deployed ones, on
    whose states the actor is held near the original policy; not counted in ``blocks`` or
    ``episodes``. Needs a shift of the scenario distribution alone (``env.scenarios.*``).
    ``settle``: while the selected policy meets every target on the held-out scenarios (its
    :func:`selection_key` has no excess; the frozen policy too, if it already does), learning
    pauses and the selected policy is deployed without exploration noise; a deployed block
    with a failure or the safety action in more than :data:`SAFETY_BUDGET` of its episodes
    resumes learning from it. On by default (docs/adapt.md: without it the policy keeps
    drifting after it met the targets).

    Raises:
        AdaptError: Bad arguments, a folder that holds another adaptation, or (``resume``) one
            with nothing to resume.
        ConfigError: A bad ``--set``.
    """
    import torch
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.vec_env import VecNormalize

    from safeswitch.core.registry import logic_names
    from safeswitch.training.config import TrainConfig, dump_config
    from safeswitch.training.policies import TrainedPolicy, load_policy
    from safeswitch.training.ppo import SwitchPPO
    from safeswitch.training.run import LearningEnv, learner_env

    rehearsal = REHEARSAL if rehearsal is None else rehearsal
    noise_decay = NOISE_DECAY if noise_decay is None else noise_decay
    asked: dict[str, Any] = {
        "model": str(model), "switching": switching, "settings": list(settings),
        "episodes": episodes, "block": block, "n_envs": n_envs, "seed": seed,
        "eval_episodes": eval_episodes, "eval_seed": eval_seed, "rehearsal": rehearsal,
        "noise_decay": noise_decay, "rollback": rollback, "settle": settle,
    }  # fmt: skip
    if noise is not None:  # asked only when given: adaptations asked before it resume as asked
        if not (math.isfinite(noise) and 0 < noise <= 1):
            raise AdaptError(f"--noise must be a standard deviation in (0, 1], got {noise}")
        asked["noise"] = noise
    if not (math.isfinite(noise_decay) and 0 < noise_decay <= 1):
        raise AdaptError(f"--noise-decay must be a share in (0, 1], got {noise_decay}")
    counts = {"episodes": episodes, "block": block, "n_envs": n_envs,
              "eval_episodes": eval_episodes}  # fmt: skip
    for name, count in counts.items():
        if count < 1:
            raise AdaptError(f"--{name.replace('_', '-')} must be at least 1, got {count}")
    rehearsed = rehearsal_count(rehearsal, n_envs)
    if switching not in logic_names():
        raise AdaptError(
            f"--switching {switching!r} is not a registered logic "
            f"(known: {', '.join(logic_names())})"
        )
    folder = Path(out)
    checkpoint = folder / "checkpoint"
    if resume:
        record = folder / "adapt.json"
        if not record.is_file():
            raise AdaptError(f"--resume: {folder} holds no adaptation (no adapt.json)")
        if json.loads(record.read_text(encoding="utf-8")) != json.loads(json.dumps(asked)):
            raise AdaptError(
                f"--resume: {folder} holds an adaptation asked differently; ask the same "
                "(--model, --switching, --set, --episodes, --block, --seed, --noise, "
                "--noise-decay, --rehearsal, --rollback, --settle)"
            )
        if (folder / "summary.json").is_file():
            raise AdaptError(f"--resume: the adaptation in {folder} is already complete")
        if not (checkpoint / "state.json").is_file():
            raise AdaptError(
                f"--resume: {folder} has no complete block yet; delete it and start again"
            )
    policy = load_policy(model)
    config = policy.config
    if not isinstance(config, TrainConfig):
        raise AdaptError(
            f"the policy in {policy.path} was trained on {config.env_id}; adapt serves the "
            "left turn's policies"
        )
    original = dataclasses.replace(config.deployed_env, switching=switching)
    shifted = scene_settings(original, settings)  # a bad --set fails before anything is written
    if rehearsed and dataclasses.replace(shifted, scenarios=original.scenarios) != original:
        raise AdaptError(
            "--rehearsal replays the original scenarios on the shifted plant: it needs a shift "
            "of the scenario distribution alone (--set env.scenarios.KEY=VALUE); this one "
            "changes more, so ask --rehearsal 0"
        )
    traffic = config.traffic_settings
    if not resume:
        prepare_output_dir(folder)
        write_json(folder / "adapt.json", asked)
    torch.set_num_threads(1)

    from safeswitch.leftturn.vec_env import LeftTurnVecEnv

    vec = LeftTurnVecEnv(n_envs, config=shifted, seed=seed, traffic=traffic)
    vec.rehearse(original, rehearsed)
    shaping, constraints = learning_terms(config, vec.task.reasons)
    learning = LearningEnv(vec, shaping, config.ppo.gamma, constraints, switching)
    source = checkpoint if resume else policy.path
    state: dict[str, Any] = {"blocks": [], "frozen": None}
    if resume:
        state = json.loads((checkpoint / "state.json").read_text(encoding="utf-8"))
        vec.episode_counters = np.asarray(state["episode_counters"], dtype=np.int64)
        learning.restore(state)
    else:
        trained = policy.path / "metrics.json"  # the multipliers its training ended with
        if trained.is_file():
            learning.restore(json.loads(trained.read_text(encoding="utf-8")))
    env = VecNormalize.load(str(source / "vecnormalize.pkl"), learning.env)
    env.training = False  # the observation statistics stay the original's
    ppo = SwitchPPO.load(source / "model.zip", env=learner_env(env, config), device="cpu")
    # Exploration as training left it: a learned noise as it ended, an annealed one at its
    # final size, held (its schedule runs over one learn call; here progress would restart it
    # at log_std_init). Or the size asked; a checkpoint keeps the size it had.
    size = math.log(noise) if noise is not None else ppo.log_std_final
    if not resume and size is not None:
        with torch.no_grad():
            ppo.policy.log_std.fill_(size)
    ppo.log_std_final = None
    # The trust region: the value function, trained on the original distribution, learns the
    # shift's returns before the actor moves, and the actor then moves slowly.
    # (A checkpoint keeps the schedule and the optimiser's moments: a resumed run goes on.)
    if not resume:
        ppo.schedule_actor(ACTOR_LEARNING_RATE, ACTOR_FROZEN_STEPS, ACTOR_RAMP_STEPS)
    if rehearsed:  # on the rehearsed distribution, the actor is held near the original policy
        ppo.anchor_to(policy.model.policy, vec.rehearsing, ANCHOR_WEIGHT)
    # The deployment's seed, not the training's: SB3 reseeds torch and the environments with
    # the model's seed when it loads (three deployment seeds were otherwise one). Seeding the
    # environments restarts their episode counts: a resumed run takes its own back, so its
    # scenarios go on where they stopped.
    ppo.set_random_seed(seed)
    if resume:
        vec.episode_counters = np.asarray(state["episode_counters"], dtype=np.int64)

    def current() -> TrainedPolicy:
        return TrainedPolicy(ppo, env if config.ppo.normalize_observations else None, config,
                             folder)  # fmt: skip

    held_out_seed = eval_seed + 1

    def held_out(candidate: Any) -> dict[str, Any]:
        """A candidate on the held-out scenarios of the shift and of the original distribution
        (what the selection reads; the summary's evaluations use other scenarios)."""
        return {
            "shifted": _brief(_evaluation(candidate, shifted, traffic, eval_episodes,
                                          held_out_seed)),
            "original": _brief(_evaluation(candidate, original, traffic, eval_episodes,
                                           held_out_seed)),
        }  # fmt: skip

    chosen = folder / "selected"
    if state["frozen"] is None:  # the frozen policy, measured once before it learns
        frozen_held_out = held_out(policy)
        frozen = {
            "shifted": _brief(_evaluation(policy, shifted, traffic, eval_episodes, eval_seed)),
            "original": _brief(_evaluation(policy, original, traffic, eval_episodes, eval_seed)),
            "held_out": frozen_held_out["shifted"],
            "held_out_original": frozen_held_out["original"],
        }
        state["frozen"] = frozen
        # The frozen policy is the first candidate: adapting never hands back a worse one.
        state["selected"] = {"block": 0, "key": selection_key(frozen_held_out, frozen),
                             "held_out": frozen_held_out}  # fmt: skip
        state["settled"] = settle and meets_targets(state["selected"]["key"])
        write_snapshot(chosen, ppo, env, state["selected"])
    bar = Progress(episodes, "adapt", enabled=progress)
    deployed = sum(b["episodes"] for b in state["blocks"])
    bar.update(deployed)

    def finish_block(stats: dict[str, Any]) -> None:
        stats["settled"] = settled = bool(state["settled"])
        # settled, the deployed policy is the selected one: its held-out evaluation stands
        measured = state["selected"]["held_out"] if settled else held_out(current())
        stats["held_out"], stats["held_out_original"] = measured["shifted"], measured["original"]
        if learning.constrained is not None:  # where the constraints' multipliers stand
            multipliers = learning.constrained.multipliers.items()
            stats["multipliers"] = {n: round(m.value, 6) for n, m in multipliers}
        state["blocks"].append(stats)
        bar.update(stats["episodes"])
        stats["rolled_back"] = False
        if settled:  # the field says whether the selected policy still meets the targets
            share = stats["safety_activation_episodes"] / stats["episodes"]
            # learning resumes at the next rollout (this one was drawn without noise)
            state["settled"] = not (stats["failures"] or share > SAFETY_BUDGET)
        else:
            key = selection_key(measured, state["frozen"])
            better = key < tuple(state["selected"]["key"])
            if better:
                state["selected"] = {"block": len(state["blocks"]), "key": key,
                                     "held_out": measured}  # fmt: skip
                # Written before the checkpoint: interrupted between the two, a resumed run
                # replays this block exactly and writes it again.
                write_snapshot(chosen, ppo, env, state["selected"])
            state["settled"] = settle and meets_targets(state["selected"]["key"])
            if not better and (rollback or state["settled"]):
                # not deployed further: on from (or settled on) the selected policy and its
                # optimiser
                ppo.set_parameters(str(chosen / "model.zip"), device="cpu")
                stats["rolled_back"] = True
            # A restored policy does not learn from the rejected policy's rollout (learning
            # resumes with the next one: NoiseSchedule), a settled one not even from its own.
            ppo.learning_paused = stats["rolled_back"] or state["settled"]
        state.update(episode_counters=vec.episode_counters.tolist(), **learning.state())
        write_snapshot(checkpoint, ppo, env, state)  # renamed whole

    monitor = DeploymentMonitor(vec, shifted, traffic, block, episodes - deployed, finish_block)
    if "noise_start" not in state:  # the log standard deviation at the first deployed episode
        state["noise_start"] = ppo.policy.log_std.detach().numpy().tolist()
    noise_schedule = NoiseSchedule(
        np.asarray(state["noise_start"]), math.log(noise_decay),
        lambda: (episodes - monitor.remaining + len(monitor.rows)) / episodes,
        settled=lambda: bool(state["settled"]),
    )  # fmt: skip
    started = time.perf_counter()
    try:
        if deployed < episodes:
            ppo.learn(
                total_timesteps=10**12,
                callback=CallbackList([monitor, noise_schedule, *learning.schedules()]),
                reset_num_timesteps=False, progress_bar=False,
            )  # fmt: skip
    finally:
        bar.close()
    wall = time.perf_counter() - started
    ppo.set_parameters(str(chosen / "model.zip"), device="cpu")  # the selected policy
    _save_policy(
        folder, ppo, env, dump_config(dataclasses.replace(config, deploy_switching=switching))
    )
    adapted = load_policy(folder)
    summary = {
        **asked,
        "shift": list(settings),
        "blocks": state["blocks"],
        "shifted": {
            "frozen": state["frozen"]["shifted"],
            "adapted": _brief(_evaluation(adapted, shifted, traffic, eval_episodes, eval_seed)),
        },
        "original": {
            "frozen": state["frozen"]["original"],
            "adapted": _brief(_evaluation(adapted, original, traffic, eval_episodes, eval_seed)),
        },
        "frozen_held_out": state["frozen"]["held_out"],
        "frozen_held_out_original": state["frozen"]["held_out_original"],
        "selected_block": state["selected"]["block"],
        "collisions": sum(b["collisions"] for b in state["blocks"]),
        "failures": sum(b["failures"] for b in state["blocks"]),
        "wall_time_s": round(wall, 1),
        "torch_threads": 1,
    }
    write_json(folder / "summary.json", summary)
    try:
        from safeswitch.report.figures import adaptation_figure

        adaptation_figure(summary, folder / "adaptation.png")
    except Exception as exc:  # a figure must never cost a finished adaptation
        print(f"warning: adaptation.png not written: {exc}")
    return summary


def selection_key(measured: dict[str, Any], frozen: dict[str, Any]) -> tuple[float, float]:
    """How a candidate policy ranks (lower is better), from its held-out evaluations
    ``measured`` (``shifted``, ``original``) against the frozen policy's on the same scenarios
    (``frozen``: ``held_out``, ``held_out_original``): its excess over the targets first — a
    collision outranks any excess; the safety action in at most :data:`SAFETY_BUDGET` of the
    episodes of the shift, with an efficiency there no lower than the frozen policy's; on the
    original distribution, the safety action in no more of the episodes than the frozen
    policy's (no forgetting; a bound of :data:`SAFETY_BUDGET` would pass a policy that forgot
    a little when the frozen one sits under it) and the efficiency within
    :data:`EFFICIENCY_TOLERANCE` of the frozen policy's — then the shift's efficiency."""
    shift, original = measured["shifted"], measured["original"]
    if shift["collisions"] or original["collisions"]:
        return (1e9, 0.0)  # finite: the key is kept in JSON

    def share(summary: dict[str, Any]) -> float:
        return summary["safety_activation_episodes"] / summary["episodes"]

    before, before_shift = frozen["held_out_original"], frozen["held_out"]
    excess = (
        max(0.0, share(shift) - SAFETY_BUDGET)
        + max(0.0, before_shift["mean_efficiency"] - shift["mean_efficiency"])
        + max(0.0, share(original) - share(before))
        + max(0.0, before["mean_efficiency"] - EFFICIENCY_TOLERANCE - original["mean_efficiency"])
    )
    return (round(excess, 12), -round(float(shift["mean_efficiency"]), 12))


def meets_targets(key: Sequence[float]) -> bool:
    """Whether a :func:`selection_key` is that of a policy within every target."""
    return float(key[0]) == 0.0


def rehearsal_count(share: float, n_envs: int) -> int:
    """The environments that rehearse: ``share`` of ``n_envs``, rounded, at least one if
    ``share`` > 0, and at least one left deployed.

    Raises:
        AdaptError: ``share`` outside [0, 1), or too large for ``n_envs``.
    """
    if not (math.isfinite(share) and 0 <= share < 1):
        raise AdaptError(f"--rehearsal must be a share in [0, 1), got {share}")
    count = max(1, round(share * n_envs)) if share > 0 else 0
    if count >= n_envs:
        raise AdaptError(
            f"--rehearsal {share} of {n_envs} environments leaves none deployed; ask a smaller "
            "share or more --n-envs"
        )
    return count


def learning_terms(config: Any, reasons: Sequence[str]) -> tuple[Any, Any]:
    """The training's shaping and constraints as they apply under the deployment logic (its
    ``reasons``): reason penalties and reason-counted constraints keep the reasons that logic
    has (a ``safety`` constraint left with none counts every safety action, as without
    reasons), ``overrule`` and the counterfactual penalty (``guarded``'s) are dropped."""
    known = set(reasons)
    penalties = {k: v for k, v in config.shaping.reason_penalties.items() if k in known}
    shaping = dataclasses.replace(
        config.shaping,
        reason_penalties=penalties,
        reason_penalties_initial_scale=(
            config.shaping.reason_penalties_initial_scale if penalties else 1.0
        ),
        counterfactual_penalty=0.0,
    )
    constraints = config.constraints
    changes: dict[str, Any] = {"overrule": None}
    for name in ("comfort", "speeding", "safety", "clear_time", "uncleared"):
        given = getattr(constraints, name)
        if given is not None and given.reasons:
            kept = tuple(r for r in given.reasons if r in known)
            changes[name] = dataclasses.replace(given, reasons=kept)
    return shaping, dataclasses.replace(constraints, **changes)


def _save_policy(folder: Path, model: Any, env: Any, config_text: str) -> None:
    """The adapted policy as a run directory ``evaluate --model`` accepts (with the files its
    configuration names)."""
    from safeswitch.training.config import write_config_with_files

    write_config_with_files(folder, config_text)
    write_policy_files(folder, model, env)


class NoiseSchedule(BaseCallback):
    """Before each rollout, the exploration noise's log standard deviation: ``start`` plus
    ``change`` times the share of the episodes deployed so far (``progress()``). Set before the
    rollout, so the update that follows computes its ratios under the noise the actions were
    drawn with; a rolled-back policy takes the scheduled noise at the next rollout. While
    ``settled()``, the rollout is drawn without noise (:data:`SETTLED_LOG_STD`) and the update
    after it is skipped (``learning_paused``): learning resumes with a rollout drawn with the
    scheduled noise."""

    def __init__(
        self, start: np.ndarray, change: float, progress: Callable[[], float],
        settled: Callable[[], bool] = lambda: False,
    ) -> None:  # fmt: skip
        super().__init__()
        self.start, self.change, self.progress, self.settled = start, change, progress, settled

    def _on_rollout_start(self) -> None:
        import torch

        paused = self.settled()
        model: Any = self.model  # a SwitchPPO
        model.learning_paused = paused
        value = self.start + self.change * min(1.0, self.progress())
        if paused:
            value = np.full_like(self.start, SETTLED_LOG_STD)
        log_std: Any = self.model.policy.log_std
        with torch.no_grad():
            log_std.copy_(torch.as_tensor(value, dtype=torch.float32))

    def _on_step(self) -> bool:
        return True


class DeploymentMonitor(BaseCallback):
    """Counts the deployed episodes (not the rehearsing environments') block by block; at the
    end of the rollout in which a block fills, hands its summary to ``finish`` (see
    :meth:`summary`); once ``episodes`` have been deployed, stops PPO (after it has learned
    from the last rollout).

    Args:
        vec: The batched environment (its ``reset_infos`` name each episode's scenario).
        config: The scene deployed in (the oracle's, for the efficiency).
        traffic: Its traffic (``None``: the paper's scene).
        block: Episodes per block.
        episodes: Episodes to deploy.
        finish: Called with each block's summary.
    """

    def __init__(
        self, vec: Any, config: Any, traffic: Any, block: int, episodes: int,
        finish: Callable[[dict[str, Any]], None],
    ) -> None:  # fmt: skip
        super().__init__()
        self.vec, self.config, self.traffic = vec, config, traffic
        self.size, self.remaining, self.finish = block, episodes, finish
        self.rows: list[dict[str, Any]] = []
        self._scenario: list[dict[str, float]] = []
        self._stop = False

    def _on_training_start(self) -> None:
        self.rehearsing = self.vec.rehearsing  # replays, not deployment: not counted
        # after SB3's reset: every environment's current episode
        self._scenario = [dict(info["scenario"]) for info in self.vec.reset_infos]

    def _on_step(self) -> bool:
        if self._stop:
            return False
        infos, dones = self.locals["infos"], self.locals["dones"]
        for i in np.flatnonzero(dones):
            if self.remaining - len(self.rows) > 0 and not self.rehearsing[i]:
                episode = infos[i]["episode"]
                kept = ("collision", "lost_control", "safety_steps", "speeding_steps",
                        "time_to_clear")  # fmt: skip
                self.rows.append({"scenario": self._scenario[i], **{k: episode[k] for k in kept}})
            self._scenario[i] = dict(self.vec.reset_infos[i]["scenario"])
        return True

    def _on_rollout_end(self) -> None:
        while len(self.rows) >= min(self.size, self.remaining) > 0:
            take = min(self.size, self.remaining)
            block, self.rows = self.rows[:take], self.rows[take:]
            self.remaining -= take
            self.finish(self.summary(block))
        if self.remaining <= 0:
            self._stop = True

    def summary(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        """A block's deployed episodes, summarised (efficiency against the oracle on the same
        scenarios, in the paper's scene)."""
        from safeswitch.evaluation.oracle import Oracle, efficiency
        from safeswitch.leftturn.make import build_task
        from safeswitch.leftturn.scenarios import Scenarios

        collision = np.array([bool(r["collision"]) for r in rows])
        lost = np.array([bool(r["lost_control"]) for r in rows])
        out: dict[str, Any] = {
            "episodes": len(rows),
            "collisions": int(collision.sum()),
            "failures": int((collision | lost).sum()),
            "safety_activation_episodes": int(sum(r["safety_steps"] > 0 for r in rows)),
            "speeding_episodes": int(sum(r["speeding_steps"] > 0 for r in rows)),
        }
        if self.traffic is None:
            task = build_task(None, self.config)
            fields = ("ego_start_distance", "ego_speed", "north_speed", "arrival_offset")
            scenarios = Scenarios(
                *(np.array([r["scenario"][f] for r in rows], dtype=np.float64) for f in fields)
            )
            oracle = Oracle(task).plan(scenarios, full=False).time_to_clear
            time = np.array([float(r["time_to_clear"]) for r in rows])
            out["mean_efficiency"] = float(
                np.nanmean(efficiency(oracle, time, task.config.episode.horizon_s))
            )
        return out
