"""The training configuration: PPO with the paper's Table II as defaults.

Every field is documented; the docstrings double as the reference for the packaged
``safeswitch/configs/*.yaml`` (``--config NAME``). A
configuration is loaded from YAML with unknown keys rejected by name, and the resolved
configuration is saved with every run.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import gymnasium as gym
import yaml

from safeswitch.core.config import (
    Bounds,
    ConfigError,
    check,
    check_bounds,
    from_dict,
    move_keys,
    to_dict,
)
from safeswitch.core.registry import logic_names, logic_params, plain_env_id
from safeswitch.evaluation.planner_config import GapPlannerConfig, PlannerConfig
from safeswitch.leftturn.config import (
    TRAFFIC_PRESETS,
    LeftTurnConfig,
    ScenarioConfig,
    TrafficConfig,
    episode_horizon_s,
    traffic_config,
)


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters: the paper's Table II, nothing else (our departures from it are
    the ``policy`` section; the learning-only reward terms the ``shaping`` section).

    Attributes:
        learning_rate: Adam step size.
        n_steps: Horizon: ticks collected per environment per update.
        n_minibatches: Minibatches per epoch (SB3's ``batch_size = n_steps · n_envs / this``).
        n_epochs: Passes over each rollout.
        gamma: Discount factor.
        gae_lambda: GAE λ.
        clip_range: PPO clipping ε.
        ent_coef: Entropy coefficient.
        vf_coef: Value-function loss coefficient.
        max_grad_norm: Gradient clipping threshold.
        net_arch: Hidden units per layer, for the policy and (separately) the value network.
        activation: Hidden-layer non-linearity (Table II: Tanh; the text's "ReLU" is the
            alternative).
        normalize_observations: Running observation normalisation (``VecNormalize``).
        normalize_rewards: Running return-based reward scaling (``VecNormalize``).
    """

    learning_rate: Annotated[float, Bounds(0, 1, low_open=True, high_open=True)] = 2.5e-4
    n_steps: Annotated[int, Bounds(2)] = 128
    n_minibatches: Annotated[int, Bounds(1)] = 4
    n_epochs: Annotated[int, Bounds(1)] = 4
    gamma: Annotated[float, Bounds(0, 1, low_open=True)] = 0.99
    gae_lambda: Annotated[float, Bounds(0, 1, low_open=True)] = 0.9
    clip_range: Annotated[float, Bounds(0)] = 0.2
    ent_coef: Annotated[float, Bounds(0)] = 0.01
    vf_coef: Annotated[float, Bounds(0)] = 0.5
    max_grad_norm: Annotated[float, Bounds(0)] = 0.5
    net_arch: tuple[int, ...] = (128, 128, 128)
    activation: Literal["tanh", "relu"] = "tanh"
    normalize_observations: bool = True
    normalize_rewards: bool = True

    def __post_init__(self) -> None:
        check_bounds(self, "ppo")
        check(
            len(self.net_arch) >= 1 and all(n >= 1 for n in self.net_arch),
            "ppo",
            "net_arch",
            self.net_arch,
            "must list one or more positive layer sizes",
        )
        if self.activation not in ("tanh", "relu"):
            raise ConfigError(f"ppo.activation={self.activation!r} is not 'tanh' or 'relu'")


@dataclass(frozen=True)
class EnvPPOConfig(PPOConfig):
    """:class:`PPOConfig` of a Gymnasium plant (:class:`EnvTrainConfig`): Table II but for three
    settings, the left turn's recipes' own — step size 5e-4, GAE λ 0.98, 8 epochs — with Table
    II's learned exploration noise (the ``policy`` section's defaults). Measured on three seeds
    of every plant (docs/training.md, "One recipe for every plant"): the left turn's ``paper``
    recipe meets every target with it, ``certified`` keeps its figures, highway-env needs the
    Safety controller on fewer steps for a higher return, the user's plant needs it on none
    even with the penalty alone; car following keeps its targets with the fit toward the
    interventions (the default) for about 10 % less return, and with the penalty alone needs
    the Safety controller on 2.5 % of steps on one seed of three. Table II's values (2.5e-4,
    0.9, 4) train the paper's PPO as written."""

    learning_rate: Annotated[float, Bounds(0, 1, low_open=True, high_open=True)] = 5e-4
    n_epochs: Annotated[int, Bounds(1)] = 8
    gae_lambda: Annotated[float, Bounds(0, 1, low_open=True)] = 0.98


@dataclass(frozen=True)
class PolicyConfig:
    """How the policy and its optimiser depart from Table II (all ours; the defaults are SB3's
    and Table II's, so an empty section is the paper's PPO).

    Attributes:
        learning_rate_final: The step size is annealed linearly from ``ppo.learning_rate`` at
            the start to this at the end of the run (``null``: constant, Table II).
        fast_tanh: With ``ppo.activation: tanh``, compute it with numpy's kernel in the forward
            pass (the same function to float32 rounding; a PPO update about a fifth faster on
            this CPU build of torch; off by default so that earlier runs reproduce; see
            :mod:`safeswitch.training.activations`).
        log_std_init: Initial log standard deviation of the Gaussian policy (SB3's default 0
            makes the first actions mostly noise on a [-1, 1] throttle).
        learn_log_std: Learn the log standard deviation (SB3's default); ``false`` keeps the
            exploration noise at ``log_std_init`` (for a warm-started actor).
        log_std_final: With ``learn_log_std: false``, the exploration noise is annealed: its
            log standard deviation falls linearly from ``log_std_init`` at the start to this at
            the end of the run, set before each rollout (``null``: a constant noise).
        actor_learning_rate: The actor's own learning rate (``null``: ``ppo.learning_rate``
            for everything, as in Table II). See :mod:`safeswitch.training.ppo`.
        actor_frozen_steps: Timesteps before the actor starts learning (value function only).
        actor_ramp_steps: Timesteps over which the actor's rate then rises from 0.
        initial_action: The policy's mean action at the start (the bias of its output layer;
            ``null``: SB3's initialisation, a mean near 0). An untrained policy whose mean is 0
            on a throttle action asks for half throttle everywhere; starting at a gentle cruise
            (-0.3) keeps early training out of the timid and the careless basins
            (docs/learning_experiments.md).
        use_sde: Generalized state-dependent exploration (gSDE, Raffin et al. 2021; SB3's
            ``use_sde``): the exploration noise is a function of the policy's last hidden
            layer with weights drawn afresh only every ``sde_sample_freq`` steps, so an
            exploring episode deviates from the mean consistently instead of tick by tick.
            ``log_std_init`` / ``log_std_final`` then scale those features (SB3's meaning):
            the action's noise is about ``exp(log_std)`` times the features' norm (4.2 on
            average, 0.9-5.7, for a fresh actor on the left turn's states).
        sde_sample_freq: With ``use_sde``, steps between fresh noise weights (-1: once per
            rollout, SB3's default).
        intervention_imitation: Learning from the Safety controller's interventions (ours;
            the HG-DAgger / EGPO line): after each PPO update the actor is also fitted toward
            the executed safety action on the rollout's states where it ran, with this weight
            on the squared difference (0: off — PPO and the penalty alone). See
            :mod:`safeswitch.training.interventions`.
        action_bound_loss: Keeping the actor's mean within the action bounds (ours, the bound
            loss of rl_games' PPO): after each PPO update the mean is pulled back to the bound
            on the rollout's states where it lies beyond one, with this weight on the squared
            excess (0: off). Every action is clipped to its bounds, so a mean far beyond one
            makes every sample of a small noise the same action and PPO stops learning there;
            see :meth:`~safeswitch.training.ppo.SwitchPPO.keep_means_in_bounds`.
        action_bound_margin: With ``action_bound_loss``, how far beyond a bound the mean may
            lie before it is pulled, in standard deviations of the exploration noise at the
            state (0: the bound itself; 1: about one sample in six still falls within).
    """

    learning_rate_final: Annotated[float | None, Bounds(0, 1, high_open=True)] = None
    fast_tanh: bool = False
    log_std_init: Annotated[float, Bounds(-5, 2)] = 0.0
    learn_log_std: bool = True
    log_std_final: Annotated[float | None, Bounds(-5, 2)] = None
    actor_learning_rate: Annotated[float | None, Bounds(0, 1, True, True)] = None
    actor_frozen_steps: Annotated[int, Bounds(0)] = 0
    actor_ramp_steps: Annotated[int, Bounds(0)] = 0
    initial_action: Annotated[float | None, Bounds(-1, 1)] = None
    use_sde: bool = False
    sde_sample_freq: Annotated[int, Bounds(-1)] = -1
    intervention_imitation: Annotated[float, Bounds(0, 1000)] = 0.0
    action_bound_loss: Annotated[float, Bounds(0, 1000)] = 0.0
    action_bound_margin: Annotated[float, Bounds(0, 10)] = 0.0

    def __post_init__(self) -> None:
        check_bounds(self, "policy")
        if self.log_std_final is not None:
            check(not self.learn_log_std, "policy", "log_std_final", self.log_std_final,
                  "anneals a fixed noise: needs learn_log_std: false")  # fmt: skip
        check(self.sde_sample_freq != 0, "policy", "sde_sample_freq", self.sde_sample_freq,
              "must be -1 (once per rollout) or a number of steps >= 1")  # fmt: skip
        check(self.use_sde or self.sde_sample_freq == -1, "policy", "sde_sample_freq",
              self.sde_sample_freq, "resamples gSDE's noise: needs use_sde: true")  # fmt: skip


@dataclass(frozen=True)
class EnvPolicyConfig(PolicyConfig):
    """:class:`PolicyConfig` of a Gymnasium plant (:class:`EnvTrainConfig`): the same
    settings, but learning from the Safety controller's interventions is on by default
    (``intervention_imitation: 1``). Measured against the penalty alone on three seeds of each
    plant at 100,000 steps — the car-following plant, a user's plant, highway-env — the Safety
    controller acted less often in seven of the nine runs and no more often in the other two
    (docs/training.md, "Learning from the interventions"); ``intervention_imitation: 0``
    trains the paper's method, PPO with ``R_ADAS`` alone. The left turn's
    :class:`PolicyConfig` keeps it off: there it hurts."""

    intervention_imitation: Annotated[float, Bounds(0, 1000)] = 1.0


@dataclass(frozen=True)
class ShapingConfig:
    """Terms added to the reward PPO learns from, and only to it: the task's reward, every
    evaluation and every figure stay the paper's (all ours; off by default; the left turn's
    records are what they read, so the generic ``--env`` training has no such section).

    Attributes:
        progress_shaping: Potential-based shaping on the ego's route progress [reward per
            metre] (0: off). It leaves the optimal policies unchanged; see
            :mod:`safeswitch.training.shaping`.
        progress_shaping_final: With ``progress_shaping`` on, ``k`` is annealed linearly
            from it at the start to this at the end of the run, one value per rollout
            (``null``: a constant ``k``).
        reason_penalties: Reason of the switching logic → reward per tick on which that
            reason's safety action ran (empty: none). It changes what PPO optimises:
            ``{"guard:backup_clear:overrules_primary": -50}`` under ``guarded`` charges the
            filter overruling the paper logic's braking about what the collision it prevents
            would forfeit; see :class:`safeswitch.training.shaping.ReasonPenalty`.
        reason_penalties_initial_scale: The reason penalties are ramped linearly from this
            share of their values at the start to all of them at the end of the run, one
            value per rollout (1: no ramp). A charge for the filter's rescues is paid mostly
            for exploration noise early on; ramped in as the noise is annealed out it charges
            the policy's own behaviour (docs/learning_experiments.md).
        clear_time_penalty: A cost per second until the ego has left its conflict zone (0:
            off): the paper's reward is all but indifferent to when the crossing is cleared;
            see :class:`safeswitch.training.shaping.ClearTimePenalty`.
        counterfactual_penalty: Under ``guarded``: reward added to each step on which the
            guard starts intervening if the episode, rolled forward from that step under the
            deployed logic alone (``deploy_switching``) with the learned action held,
            collides (0: off). It charges the collisions the paper logic alone would let
            through, and only those; see
            :class:`safeswitch.training.shaping.CounterfactualPenalty`.
        counterfactual_horizon_s: How far that counterfactual is rolled [s].
    """

    progress_shaping: Annotated[float, Bounds(0, 100, unit="per metre")] = 0.0
    progress_shaping_final: Annotated[float | None, Bounds(0, 100, unit="per metre")] = None
    reason_penalties: dict[str, float] = field(default_factory=dict)
    reason_penalties_initial_scale: Annotated[float, Bounds(0, 1)] = 1.0
    clear_time_penalty: Annotated[float, Bounds(0, 1000, unit="per second")] = 0.0
    counterfactual_penalty: Annotated[float, Bounds(-100_000, 0)] = 0.0
    counterfactual_horizon_s: Annotated[float, Bounds(0.1, 30, unit="s")] = 4.0

    def __post_init__(self) -> None:
        o = "shaping"
        check_bounds(self, o)
        penalties = self.reason_penalties
        check(isinstance(penalties, dict) and all(isinstance(k, str) for k in penalties), o,
              "reason_penalties", penalties, "must map reason names to numbers")  # fmt: skip
        for name, value in penalties.items():
            number = isinstance(value, int | float) and not isinstance(value, bool)
            ok = number and math.isfinite(value) and -1000 <= value <= 0
            check(ok, o, f"reason_penalties[{name!r}]", value, "must be in [-1000, 0] per tick")
        scale = self.reason_penalties_initial_scale
        check(scale == 1 or bool(penalties), o, "reason_penalties_initial_scale", scale,
              "ramps the reason penalties: needs reason_penalties")  # fmt: skip
        if self.progress_shaping_final is not None:
            check(self.progress_shaping > 0, o, "progress_shaping_final",
                  self.progress_shaping_final,
                  "anneals the shaping: needs progress_shaping > 0")  # fmt: skip


#: Where the keys that left ``ppo`` went (configurations written before load unchanged).
MOVED_FROM_PPO: dict[str, str] = {
    **{f"ppo.{k}": f"policy.{k}" for k in (
        "learning_rate_final", "fast_tanh", "log_std_init", "learn_log_std", "log_std_final",
        "actor_learning_rate", "actor_frozen_steps", "actor_ramp_steps", "initial_action")},
    **{f"ppo.{k}": f"shaping.{k}" for k in (
        "progress_shaping", "progress_shaping_final", "reason_penalties",
        "reason_penalties_initial_scale", "clear_time_penalty", "counterfactual_penalty",
        "counterfactual_horizon_s")},
}  # fmt: skip


#: The largest seed (NumPy's legacy seeding, which SB3 uses, takes 32 bits).
SEED_MAX = 2**32 - 1

#: Values of ``warm_start.teacher``.
TEACHERS = ("planner", "gap_planner")


@dataclass(frozen=True)
class WarmStartConfig:
    """Behaviour cloning of the planner before PPO (ours; see
    :mod:`safeswitch.training.warm_start`).

    Attributes:
        episodes: Scenarios per round (0: no warm start — PPO from a random initialisation).
        rounds: DAgger rounds after the planner's own demonstrations (the clone drives, under
            the certified switching logic, and the planner labels).
        epochs: Passes over all labels so far after each round.
        learning_rate: Adam step size of the cloning.
        teacher: Who demonstrates and labels: ``planner`` (the single-car scene's planner,
            which sees only the north car) or ``gap_planner`` (the gap planner of
            :mod:`safeswitch.evaluation.traffic_planner`, which waits for a gap the certified
            filter accepts among all the traffic; needs ``traffic``).
        planner: Tuning of the planner that demonstrates and labels (default: the evaluation
            baseline's). A lower ``accel_lat`` leaves the clone, which tracks the planner's
            turn speed only approximately, a margin below the lateral comfort limit.
        gap_planner: Tuning of the gap planner (``teacher: gap_planner``).
        policy: Start from this trained policy instead of cloning a teacher: a run folder
            (or a checkpoint, or a shipped policy's name) whose network has this run's
            architecture; its weights and observation statistics become the run's starting
            point (fine-tuning, e.g. after ``benchmarks/search_refinement.py``). Excludes
            ``episodes``.
        freeze_obs_stats: Keep ``VecNormalize``'s observation statistics at the
            demonstrations' (or ``policy``'s) for the rest of the run. The clone was fitted
            to inputs normalised with exactly these; left running, they drift with PPO's state
            distribution and move the clone's cut/yield decisions (measured: the clone with the
            statistics of a 1.2 M-step run went from 21 to 205 episodes with a safety action).
        extend_inputs: ``policy`` may observe fewer values than this run, its observation
            being the first values of this run's (ours; e.g. the single-car scene's policy
            starting a run in traffic, whose observation is the paper's six values, then the
            other vehicles'): the first layers' weights for the extra inputs start at zero, so
            the network starts out computing what ``policy``'s did, and the observation
            statistics start from ``policy``'s for its values and are re-estimated on this
            run's states (needs ``freeze_obs_stats: false``; a curriculum from one scene to
            another, no demonstrations).
    """

    episodes: Annotated[int, Bounds(0)] = 0
    rounds: Annotated[int, Bounds(0)] = 2
    epochs: Annotated[int, Bounds(1)] = 8
    learning_rate: Annotated[float, Bounds(0, 1, True, True)] = 1e-3
    teacher: Literal["planner", "gap_planner"] = "planner"
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    gap_planner: GapPlannerConfig = field(default_factory=GapPlannerConfig)
    policy: str | None = None
    freeze_obs_stats: bool = True
    extend_inputs: bool = False

    def __post_init__(self) -> None:
        check_bounds(self, "warm_start")
        check(not self.extend_inputs or (self.policy is not None and not self.freeze_obs_stats),
              "warm_start", "extend_inputs", self.extend_inputs,
              "needs a policy to start from and freeze_obs_stats: false (the extra inputs' "
              "statistics are learned)")  # fmt: skip
        check(self.policy is None or not self.episodes, "warm_start", "policy", self.policy,
              "starts from a trained policy: leave episodes at 0 (no cloning)")  # fmt: skip
        check(self.teacher in TEACHERS, "warm_start", "teacher", self.teacher,
              f"must be one of {TEACHERS}")  # fmt: skip


#: Keys of the fine-tune phase's configuration the refinement stage sets itself.
FINETUNE_FIXED = ("refine", "warm_start", "eval_episodes")


@dataclass(frozen=True)
class RefineConfig:
    """Search-guided refinement after PPO (ours; off by default; the left turn, alone or in
    traffic; see :mod:`safeswitch.training.refine`). Each iteration drives ``scenes`` fresh training
    scenarios with the run's policy, searches better action sequences where it fails or
    could clear sooner (the cross-entropy method of :mod:`safeswitch.evaluation.search`,
    started from the policy's own actions) and fits the actor to them; every iteration is
    validated and the run keeps the best (``refine.csv``).

    Attributes:
        iterations: Refinement iterations after PPO (0: none).
        scenes: Training scenarios driven per iteration.
        population: Sequences per scene and round of the search where the policy fails
            (never clears, or a dirty tick: a comfort limit broken, the speed limit passed,
            the safety action executed).
        rounds: Rounds of that search.
        speed_scenes: Scenes the policy drives cleanly searched for a clean clear at least
            ``min_gain_s`` sooner.
        speed_population: Sequences per scene and round of that search.
        speed_rounds: Its rounds.
        min_gain_s: How much sooner a clean clear must be to become a label [s].
        knot: Decisions per knot of the search's perturbations (interpolated between: a
            smooth change of the policy's actions, which the actor can fit).
        margin: A label must stay clean with every action this much higher and lower too
            (the search ranks each sequence by the dirty ticks of all three episodes; 0: its
            own alone): room for a fitted policy, which tracks its labels only approximately.
        lock_s: Where the policy's episode has a dirty tick, the search keeps the policy's own
            actions up to this long before the first one and searches only the rest [s]
            (``null``: the whole sequence). The labels before the fix are then the states the
            policy itself drives through, and the fix starts from one of them: a DAgger-style
            correction where a policy fitted to a label changed from the start arrives a little
            off it (ours).
        uncleared_dirty_ticks: Where the policy never clears, a searched clear with at most
            this many dirty ticks becomes a label too (0: only a clean clear): a scene only a
            brief touch of the filter or a comfort limit lets any driver clear (the band of
            docs/learning_experiments.md, "The ceiling") is then taught to clear (ours).
        weight: How many times an improved scene's samples count in the fit.
        epochs: Passes of the fit (mean squared error on the actor's mean, Adam).
        learning_rate: The fit's step size.
        env: Changes of the training ``env`` for the search alone (a mapping merged key by
            key, as ``train_only`` is; ``null``: none), e.g. ``{certified: {progress_factor:
            1.15}}`` (a stricter filter) or ``{rewards: {comfort_accel_lat: 2.7}}`` (stricter
            comfort limits for what counts as a dirty tick): a label clean under stricter rules
            leaves the fitted policy, which tracks it only approximately, room before the
            deployed filter acts or a comfort limit breaks. Deployment and validation keep
            the env's.
        finetune: A constrained PPO phase after the search (ours; ``null``: none): a mapping
            merged into the run's configuration for it, key by key (as ``refine.env`` is into
            ``env``), naming at least ``timesteps``, e.g. a small fixed exploration noise, a
            smaller actor step, the constraints on from the first step and validation every
            100,000 steps. It starts from the search's fastest iteration with no collision
            (``warm_start.policy``; the budgets are left to the phase's constraints), trains in
            ``refine/finetune/`` with the run's constraints, validation and selection, and its
            selected policy becomes the run's if the run's criterion ranks it at least as high
            as PPO's own. A policy fitted to search labels touches the filter near their edge;
            the safety constraint's multiplier pulls it back toward its budget at a small cost
            in time (within it on one of three seeds of the ``certified`` recipe:
            docs/learning_experiments.md).
    """

    iterations: Annotated[int, Bounds(0, 50)] = 0
    scenes: Annotated[int, Bounds(1)] = 1000
    population: Annotated[int, Bounds(2)] = 128
    rounds: Annotated[int, Bounds(1)] = 8
    speed_scenes: Annotated[int, Bounds(0)] = 300
    speed_population: Annotated[int, Bounds(2)] = 32
    speed_rounds: Annotated[int, Bounds(1)] = 6
    min_gain_s: Annotated[float, Bounds(0, unit="s")] = 0.1
    knot: Annotated[int, Bounds(1)] = 5
    margin: Annotated[float, Bounds(0, 1, high_open=True)] = 0.0
    lock_s: Annotated[float | None, Bounds(0, 120, unit="s")] = None
    uncleared_dirty_ticks: Annotated[int, Bounds(0, unit="ticks")] = 0
    weight: Annotated[int, Bounds(1, 100)] = 5
    epochs: Annotated[int, Bounds(1)] = 20
    learning_rate: Annotated[float, Bounds(0, 1, True, True)] = 1e-4
    env: dict[str, Any] | None = None
    finetune: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        check_bounds(self, "refine")
        if self.finetune is not None:
            check(self.iterations > 0, "refine", "finetune", "set",
                  "fine-tunes the search's policy: needs iterations > 0")  # fmt: skip
            check(isinstance(self.finetune, dict) and "timesteps" in self.finetune, "refine",
                  "finetune", self.finetune, "must be a mapping that names timesteps")  # fmt: skip
            for key in FINETUNE_FIXED:
                check(key not in self.finetune, "refine.finetune", key, self.finetune.get(key),
                      "is set by the stage: the phase starts from the searched policy",
                      )  # fmt: skip


@dataclass(frozen=True)
class StressConfig:
    """A second validation set where rare collisions concentrate (ours; off by default).

    A policy that collides once in 3,000 random scenarios shows no collision on a validation
    set of 1,000 — and a million-scenario campaign finds hundreds
    (docs/learning_experiments.md). Where the collisions concentrate is known from such a
    campaign (under ``paper``: the north car arriving 1.0–3.5 s after the ego, between
    cutting and yielding), so the validation also drives the policy on ``episodes``
    scenarios drawn from that narrower distribution, and its collisions there count with the
    validation set's (the criteria's first term). Only a policy that would otherwise become
    the best is driven there (its collisions can only lower its rank, so the others need not
    be), and only until its collisions there rule it out (in chunks of 5,000). 20,000
    scenarios: a policy that collides in 5 of 10,000 of them shows none in 5,000 one time in
    twelve, in 20,000 one time in 22,000.

    Attributes:
        episodes: Scenarios of the stress set.
        seed: Their seed (differs from the training, evaluation and validation seeds).
        scenarios: Their distribution (a whole
            :class:`~safeswitch.leftturn.config.ScenarioConfig`; keys not given keep its
            defaults, not the environment's).
    """

    episodes: Annotated[int, Bounds(1)] = 20_000
    seed: Annotated[int, Bounds(0, SEED_MAX)] = 5_000_011
    scenarios: ScenarioConfig = field(default_factory=ScenarioConfig)

    def __post_init__(self) -> None:
        check_bounds(self, "validation.stress")


@dataclass(frozen=True)
class ValidationConfig:
    """Model selection on a validation set (ours; off by default). Every ``every`` timesteps
    the deterministic policy drives ``episodes`` random scenarios that are neither trained on
    nor tested on, and the run keeps the policy with the highest mean return there — the
    paper's own criterion: "the non-normalized cumulative reward is the main criteria for
    learned model validation" (Section V). PPO's policy moves between basins late in a run
    (docs/learning_experiments.md); the last policy is not always the best one.

    Attributes:
        every: Timesteps between two validations (0: none; the run's policy is its last).
        episodes: Scenarios of the validation set.
        seed: Their seed (differs from the training seed and from ``eval_seed``).
        start: Timesteps before the first validation (early policies are no candidates).
        switching: The switching logic the policy is validated under (``null``: the one it
            is deployed under, ``deploy_switching``, by default the one it trains with). Ours:
            a policy trained under one logic and meant to be deployed under another (trained
            under ``guarded``, deployed under ``paper``) is selected where it will run.
        criterion: ``"return"``: the highest mean return (the paper's criterion);
            ``"collisions_then_return"`` (ours): the fewest validation collisions, then the
            highest mean return. The paper's reward has no collision term — a collision only
            ends the episode early — so two policies can score the same return with and
            without one. ``"constraints_then_return"`` (ours, with ``constraints``): the
            fewest collisions, then the smallest excess over the comfort, speeding and safety
            budgets, then over the clear-time budget, then the highest return — the
            constrained problem's priorities
            (:func:`safeswitch.training.validation.constraint_key`).
        stress: A second set where rare collisions concentrate, counted in the criterion's
            collisions (``null``: none; see :class:`StressConfig`).
        families: In traffic (ours): traffic presets (e.g. ``[test, light, medium, heavy]``)
            whose scenes the policy must keep its limits in as well. A policy about to become
            the best is also driven on ``episodes`` scenes of each (the validation seed; it
            observes what it was trained to, as under ``safeswitch evaluate --traffic
            FAMILY``), and
            ``constraints_then_return`` counts each limit (comfort, speeding, safety) at the
            worst of the validation set and these families — the issue's targets hold "at
            every density" — while clearing and the return still rank on the validation set.
            Empty: the validation set alone.
        scenes: In the paper's scene (ours): named scenario distributions (each a whole
            :class:`~safeswitch.leftturn.config.ScenarioConfig`; keys not given keep its
            defaults, as the stress set's) whose scenarios the policy must keep its limits in
            as well, counted as ``families`` are: a would-be best policy is driven on
            ``episodes`` scenarios of each (the validation seed, the deployment logic), and
            each limit counts at the worst of the validation set and these scenes
            (``worst_family`` in ``validation.csv`` names the scene). For a policy trained on
            a wider scene than it is validated on: a candidate that needs the filter only
            where the wider scene differs is not the run's policy. Empty: none.
        average: The decay of an exponential moving average of the policy's weights, updated
            after every PPO update (Polyak averaging of the weights, as Nikishin et al. 2018
            do for A2C and DDPG); 0: none. Above 0 every validation drives the averaged
            policy as well as the current one (rows of ``validation.csv`` with ``averaged`` 1
            and 0), and either can become the run's policy. A decay of 0.98 averages over
            about the last 50 updates. The average is kept in every checkpoint and resumed
            with it.
    """

    every: Annotated[int, Bounds(0)] = 0
    episodes: Annotated[int, Bounds(1)] = 500
    seed: Annotated[int, Bounds(0, SEED_MAX)] = 2_000_003
    start: Annotated[int, Bounds(0)] = 0
    switching: str | None = None
    criterion: Literal["return", "collisions_then_return", "constraints_then_return"] = "return"
    stress: StressConfig | None = None
    families: tuple[str, ...] = ()
    scenes: dict[str, ScenarioConfig] = field(default_factory=dict)
    average: Annotated[float, Bounds(0, 1, high_open=True)] = 0.0

    def __post_init__(self) -> None:
        o = "validation"
        for family in self.families:
            check(family in TRAFFIC_PRESETS, o, "families", list(self.families),
                  f"must name traffic presets ({', '.join(TRAFFIC_PRESETS)})")  # fmt: skip
        check(len(set(self.families)) == len(self.families), o, "families", list(self.families),
              "must not name a family twice (its scenes would be driven twice)")  # fmt: skip
        if self.switching is not None:
            known = ", ".join(logic_names())
            check(self.switching in logic_names(), o, "switching", self.switching,
                  f"must be null or a registered switching logic ({known})")  # fmt: skip
        check_bounds(self, o)


@dataclass(frozen=True)
class ConstraintConfig:
    """One constraint of constrained PPO (see :mod:`safeswitch.training.constraints`).

    Attributes:
        budget: What the constraint allows: a share of ticks (``comfort``, ``speeding``,
            ``overrule``), a share of episodes (``comfort_episodes``, ``safety``,
            ``uncleared``) or a mean time to clear [s] (``clear_time``), > 0.
        integral_gain: Added to the multiplier's integral term per rollout per unit of
            relative excess (``measured / budget − 1``) [reward per unit of the cost].
        proportional_gain: Multiplier per unit of the rollout's relative excess.
        max_multiplier: Upper bound of the multiplier [reward per unit of the cost].
        initial_multiplier: The multiplier at the start of the run.
        start: Timesteps before the multiplier starts to move.
        validation_budget: What ``validation.criterion: constraints_then_return`` holds the
            deterministic policy to on the validation scenarios, in the same unit (``null``:
            ``budget``). The training budget is met by the exploring policy the multipliers
            see; this one is the target the deployed policy is meant to meet.
        reasons: ``safety`` only: the switching logic's reasons whose safety actions count
            (empty: every safety action). Under ``guarded``, the paper logic's own
            (``no_gap_at_braking_point`` and the ``…:overrules_primary`` reasons) are what the
            policy meets deployed under ``paper``.
    """

    budget: Annotated[float, Bounds(0, low_open=True)]
    integral_gain: Annotated[float, Bounds(0)] = 1.0
    proportional_gain: Annotated[float, Bounds(0)] = 0.0
    max_multiplier: Annotated[float, Bounds(0)] = 100.0
    initial_multiplier: Annotated[float, Bounds(0)] = 0.0
    start: Annotated[int, Bounds(0)] = 0
    validation_budget: Annotated[float | None, Bounds(0, low_open=True)] = None
    reasons: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        o = "constraints.<cost>"
        check_bounds(self, o)
        most = self.max_multiplier
        check(self.initial_multiplier <= most, o, "initial_multiplier",
              self.initial_multiplier, f"must be in [0, max_multiplier={most}]")  # fmt: skip

    @property
    def selection_budget(self) -> float:
        """The budget validation holds the deterministic policy to."""
        return self.budget if self.validation_budget is None else self.validation_budget


@dataclass(frozen=True)
class ConstraintsConfig:
    """Constrained PPO: learning-only costs whose Lagrange multipliers the run moves to meet
    their budgets (ours; see :mod:`safeswitch.training.constraints`). Each cost is off unless
    given.

    Attributes:
        comfort: Ticks over a comfort limit, as a share of ticks.
        comfort_episodes: Episodes with a tick over a comfort limit, as a share of episodes
            (ours): a share of ticks hides a policy that breaks a limit briefly in many
            episodes — in traffic 0.1-0.3 % of ticks were 15-23 % of the scenes.
        speeding: Ticks faster than the tolerated speed (``R_v``'s best, 30 km/h by default),
            as a share of ticks.
        safety: Episodes with a safety action (of ``reasons``), as a share of episodes.
        overrule: Under ``guarded``: ticks on which the certified filter overruled the paper
            logic's own safety action (its braking was unsafe there: deployed under ``paper``
            alone, these are the episodes that collide), as a share of ticks; ``reasons``
            default to every ``…:overrules_primary`` reason of the logic.
        clear_time: The mean time until the ego clears its conflict zone [s].
        uncleared: Episodes that end with the ego not clear of its conflict zone, as a share
            of episodes.
    """

    comfort: ConstraintConfig | None = None
    comfort_episodes: ConstraintConfig | None = None
    speeding: ConstraintConfig | None = None
    safety: ConstraintConfig | None = None
    overrule: ConstraintConfig | None = None
    clear_time: ConstraintConfig | None = None
    uncleared: ConstraintConfig | None = None

    def __post_init__(self) -> None:
        for name in ("comfort", "comfort_episodes", "speeding", "clear_time", "uncleared"):
            given = getattr(self, name)
            if given is not None:
                check(not given.reasons, f"constraints.{name}", "reasons", given.reasons,
                      "are for the safety constraint only")  # fmt: skip
        for name in ("comfort", "comfort_episodes", "speeding", "safety", "overrule", "uncleared"):
            given = getattr(self, name)
            if given is not None:
                check(given.budget < 1, f"constraints.{name}", "budget", given.budget,
                      "is a share: must be < 1")  # fmt: skip

    def active(self) -> dict[str, ConstraintConfig]:
        """The constraints that are on, by cost name."""
        named = {"comfort": self.comfort, "comfort_episodes": self.comfort_episodes,
                 "speeding": self.speeding, "safety": self.safety,
                 "overrule": self.overrule, "clear_time": self.clear_time,
                 "uncleared": self.uncleared}  # fmt: skip
        return {name: c for name, c in named.items() if c is not None}


#: The configuration ``safeswitch train`` uses without ``--config``: the paper's recipe.
DEFAULT_CONFIG = "paper_scratch"


def check_run_shape(n_envs: int, ppo: PPOConfig) -> None:
    """What every training configuration must satisfy: a rollout (``n_envs`` ×
    ``ppo.n_steps``) that splits into ``ppo.n_minibatches`` equal minibatches (each value
    named)."""
    rollout = n_envs * ppo.n_steps
    if rollout % ppo.n_minibatches:
        raise ConfigError(
            f"a rollout of n_envs ({n_envs}) × ppo.n_steps ({ppo.n_steps}) = {rollout} steps "
            f"does not split into ppo.n_minibatches ({ppo.n_minibatches}) equal minibatches; "
            "change one of the three"
        )


@dataclass(frozen=True)
class TrainConfig:
    """One training run.

    Attributes:
        timesteps: Environment ticks to train for, summed over environments (Table II: 1.2 M).
        n_envs: Environments stepped as one batch (ours: 16 keeps 4 minibatches of 512).
        seed: Seed of PPO, of the networks and of the training scenarios.
        torch_threads: CPU threads torch may use.
        checkpoint_every: Save a resumable checkpoint every this many timesteps.
        eval_episodes: Random scenarios of the final evaluation.
        eval_seed: Seed of the final evaluation's scenarios (never used in training).
        deploy_switching: The switching logic the trained policy runs under: its final
            evaluation, its validation (unless ``validation.switching`` names another) and
            ``safeswitch evaluate --model`` without ``--switching`` (ours; ``null``: the logic it
            trains with). A policy trained under ``guarded`` (the paper's logic with the
            certified filter beneath it while it learns) is deployed under ``paper``.
        stagger_starts: Truncate each training environment's first episode after a random
            share of the horizon, so that the environments' episodes do not all start and
            end together (ours; off: the paper's setting). See
            :class:`~safeswitch.leftturn.vec_env.LeftTurnVecEnv`'s ``stagger``.
        ppo: PPO hyper-parameters (Table II).
        policy: How the policy and its optimiser depart from Table II (ours).
        shaping: Learning-only reward terms (ours; none by default).
        warm_start: Behaviour cloning of the planner before PPO (off by default).
        validation: Selection of the run's policy on a validation set (off by default).
        constraints: Constrained PPO: costs with self-adjusting multipliers (off by default).
        refine: Search-guided refinement of the run's policy after PPO (off by default).
        env: The environment: switching logic, ``R_ADAS`` on or off, and everything else.
        train_only: Changes of ``env`` for the training environments alone (ours; a mapping
            merged into ``env``, key by key, as ``base:`` merges (:func:`read_config`);
            ``null``: none). The validation and every
            evaluation of the run keep ``env``. E.g. ``{scenarios: {focus_share: 0.25}}``: a
            training distribution that dwells on where rare failures concentrate;
            ``{paper: {ttr_threshold_s: 2.3}}``: train against a stricter trigger of the
            paper logic than the one deployed, for a margin from it.
        traffic: Traffic from every leg (``null``: the paper's scene): a preset's name or a
            mapping of :class:`~safeswitch.leftturn.config.TrafficConfig` settings (``preset``
            to start from one).
    """

    timesteps: Annotated[int, Bounds(1)] = 1_200_000
    n_envs: Annotated[int, Bounds(1)] = 16
    seed: Annotated[int, Bounds(0, SEED_MAX)] = 0
    torch_threads: Annotated[int, Bounds(1)] = 2
    checkpoint_every: Annotated[int, Bounds(1)] = 200_000
    eval_episodes: Annotated[int, Bounds(0)] = 1000
    eval_seed: Annotated[int, Bounds(0, SEED_MAX)] = 1_000_003
    deploy_switching: str | None = None
    stagger_starts: bool = False
    ppo: PPOConfig = field(default_factory=PPOConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    shaping: ShapingConfig = field(default_factory=ShapingConfig)
    warm_start: WarmStartConfig = field(default_factory=WarmStartConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)
    constraints: ConstraintsConfig = field(default_factory=ConstraintsConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    env: LeftTurnConfig = field(default_factory=LeftTurnConfig)
    traffic: str | dict[str, Any] | None = None
    train_only: dict[str, Any] | None = None

    MOVED: ClassVar[dict[str, str]] = MOVED_FROM_PPO

    def __post_init__(self) -> None:
        o = "train"
        check_bounds(self, o)
        traffic_config(self.traffic)  # validates, naming a bad value
        check(
            self.eval_seed != self.seed,
            o,
            "eval_seed",
            self.eval_seed,
            "must differ from the training seed",
        )
        check_run_shape(self.n_envs, self.ppo)
        if self.warm_start.episodes and self.warm_start.teacher == "gap_planner":
            check(self.traffic is not None, "warm_start", "teacher", self.warm_start.teacher,
                  "needs traffic (the single-car scene has teacher: planner)")  # fmt: skip
            self.warm_start.gap_planner.check_scene(
                self.env.controllers.learned_brake, "warm_start.gap_planner"
            )
        if self.deploy_switching is not None:
            known = ", ".join(logic_names())
            check(self.deploy_switching in logic_names(), o, "deploy_switching",
                  self.deploy_switching,
                  f"must be null or a registered switching logic ({known})")  # fmt: skip
        if self.shaping.counterfactual_penalty:
            check(self.deploy_switching is not None and self.traffic is None, "shaping",
                  "counterfactual_penalty", self.shaping.counterfactual_penalty,
                  "rolls the single-car scene under deploy_switching: needs deploy_switching "
                  "and no traffic")  # fmt: skip
        command = self.env.controllers.learned_speed_command_kmh
        if command is not None:  # a teacher's or a search's throttles map to no set point
            why = (
                "drives with throttle actions, (a + 1) / 2: needs a pedal action (no "
                f"env.controllers.learned_speed_command_kmh, here {command:g})"
            )
            ws, refine = self.warm_start, self.refine
            check(not ws.episodes, "warm_start", "teacher", ws.teacher, why)
            check(not refine.iterations, "refine", "iterations", refine.iterations, why)
        clear = self.constraints.clear_time
        if clear is not None:
            horizon = self.horizon_s
            check(clear.budget < horizon, "constraints.clear_time", "budget", clear.budget,
                  f"is a mean time to clear [s]: must be below the horizon ({horizon} s)",
                  )  # fmt: skip
        v = self.validation
        constrained = bool(self.constraints.active())
        check(v.criterion != "constraints_then_return" or constrained, "validation",
              "criterion", v.criterion, "needs constraints (none are set)")  # fmt: skip
        if v.every:
            check(v.seed not in (self.seed, self.eval_seed), "validation", "seed", v.seed,
                  "must differ from the training seed and eval_seed")  # fmt: skip
        self.train_env  # noqa: B018 (validates train_only, naming a bad key or value)
        if v.stress is not None:
            check(v.stress.seed not in (self.seed, self.eval_seed, v.seed), "validation.stress",
                  "seed", v.stress.seed,
                  "must differ from the training, eval and validation seeds")  # fmt: skip
            check(self.traffic is None, "validation", "stress", "set",
                  "is for the paper's scene (a traffic scene draws its own scenarios)")  # fmt: skip
        if v.families:
            check(self.traffic is not None, "validation", "families", list(v.families),
                  "need traffic (the paper's scene has no traffic families)")  # fmt: skip
            check(v.criterion == "constraints_then_return", "validation", "families",
                  list(v.families),
                  "count only under criterion: constraints_then_return")  # fmt: skip
        if v.scenes:
            check(self.traffic is None, "validation", "scenes", list(v.scenes),
                  "are the paper's scene's (in traffic: validation.families)")  # fmt: skip
            check(v.criterion == "constraints_then_return", "validation", "scenes",
                  list(v.scenes),
                  "count only under criterion: constraints_then_return")  # fmt: skip
        if self.refine.iterations:
            check(self.env.scenario is None, "refine", "iterations", self.refine.iterations,
                  f"needs random scenarios (env.scenario is {self.env.scenario!r})")  # fmt: skip
            searched = self.refine_env  # validates refine.env, naming a bad key or value
            if self.refine.finetune is not None:
                self.finetune_config("refined")  # validates refine.finetune likewise
            for where, env in (("env", self.train_env), ("deploy_switching", self.deployed_env),
                               ("refine.env", searched)):  # fmt: skip
                check(env.switching == "certified", "refine", "iterations",
                      self.refine.iterations, "searches open loop under the certified filter "
                      f"(no sequence can collide): {where} has {env.switching!r}")  # fmt: skip

    @property
    def train_env(self) -> LeftTurnConfig:
        """The environment the policy trains in: ``env`` with ``train_only`` merged in."""
        if not self.train_only:
            return self.env
        merged = _merged(to_dict(self.env), self.train_only, "train_only")
        return from_dict(LeftTurnConfig, merged, where="train_only")

    @property
    def refine_env(self) -> LeftTurnConfig:
        """The environment the refinement searches: :attr:`train_env` with ``refine.env``
        merged in."""
        if not self.refine.env:
            return self.train_env
        merged = _merged(to_dict(self.train_env), self.refine.env, "refine.env")
        return from_dict(LeftTurnConfig, merged, where="refine.env")

    def finetune_config(self, start: str) -> TrainConfig:
        """The configuration of the refinement's fine-tune phase (``refine.finetune`` merged
        into this one), starting from the policy in ``start``; no refinement of its own, no
        evaluation (the run evaluates what it keeps)."""
        assert self.refine.finetune is not None
        merged = _merged(to_dict(self), self.refine.finetune, "refine.finetune")
        merged.update(
            refine=to_dict(RefineConfig()),
            warm_start={**to_dict(WarmStartConfig()), "policy": start},
            eval_episodes=0,
        )
        try:
            return from_dict(TrainConfig, merged, where="refine.finetune")
        except ConfigError as error:  # a bound of the phase's own configuration
            if "refine.finetune" in str(error):
                raise
            raise ConfigError(f"refine.finetune: {error}") from error

    @property
    def batch_size(self) -> int:
        """SB3's minibatch size."""
        return self.ppo.n_steps * self.n_envs // self.ppo.n_minibatches

    @property
    def deployed_env(self) -> LeftTurnConfig:
        """:attr:`env` with the logic the trained policy runs under (``deploy_switching``)."""
        if self.deploy_switching is None:
            return self.env
        return dataclasses.replace(self.env, switching=self.deploy_switching)

    @property
    def traffic_settings(self) -> TrafficConfig | None:
        """:attr:`traffic` resolved."""
        return traffic_config(self.traffic)

    @property
    def horizon_s(self) -> float:
        """How long the episodes last [s]: ``env.episode.horizon_s``, in traffic the traffic's
        ``horizon_s`` where it sets one (as :func:`~safeswitch.leftturn.make.build_task`
        builds the task)."""
        return episode_horizon_s(self.env.episode, self.traffic_settings)


def _merged(base: dict[str, Any], over: Any, where: str) -> dict[str, Any]:
    """``base`` with ``over``'s values in place of its own, mapping by mapping: a non-empty
    nested mapping changes only the keys it names; any other value (an empty mapping
    included) replaces the base's whole."""
    if not isinstance(over, dict):
        raise ConfigError(f"{where}: expected a mapping, got {over!r}")
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and value and isinstance(base.get(key), dict):
            out[key] = _merged(base[key], value, f"{where}.{key}")
        else:
            out[key] = value
    return out


#: The configurations that ship with the package, by name (``--config paper``).
PACKAGED_CONFIGS = Path(__file__).resolve().parent.parent / "configs"

#: The experiment recipes behind the learning log (``--config experimental/NAME``): records of
#: runs, kept in the source tree's ``experiments/`` — not in the package. An installed wheel
#: has none; a checkout (an editable install) finds them beside ``src/``.
EXPERIMENTS = PACKAGED_CONFIGS.parents[2] / "experiments"
EXPERIMENT_PREFIX = "experimental/"


def packaged_config_names() -> tuple[str, ...]:
    """Names of the shipped configurations (``paper``, …) and, in a source checkout, of the
    experiment recipes (``experimental/...``)."""
    shipped = [p.stem for p in PACKAGED_CONFIGS.glob("*.yaml")]
    experiments = [
        EXPERIMENT_PREFIX + p.relative_to(EXPERIMENTS).with_suffix("").as_posix()
        for p in EXPERIMENTS.rglob("*.yaml")
    ]  # an empty list where the folder is absent
    return tuple(sorted(shipped)) + tuple(sorted(experiments))


def config_path(name_or_path: str | Path) -> Path:
    """A configuration file: an existing path, a shipped configuration by name, or an
    experiment recipe (``experimental/NAME``, from ``experiments/`` in a source checkout).

    Raises:
        FileNotFoundError: None of these, naming the configurations there are.
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    name = str(name_or_path).removesuffix(".yaml")  # not with_suffix: names may hold dots
    if name.startswith(EXPERIMENT_PREFIX):
        experiment = EXPERIMENTS / f"{name.removeprefix(EXPERIMENT_PREFIX)}.yaml"
        if experiment.is_file():
            return experiment
        if not EXPERIMENTS.is_dir():
            raise FileNotFoundError(
                f"no configuration {str(name_or_path)!r}: the experiment recipes live in the "
                "repository's experiments/ folder, which an installed package does not have; "
                "run from a checkout (pip install -e .) or pass the file's path"
            )
    else:
        packaged = PACKAGED_CONFIGS / f"{name}.yaml"
        if packaged.is_file():
            return packaged
    known = packaged_config_names()
    shipped = [n for n in known if not n.startswith(EXPERIMENT_PREFIX)]
    records = len(known) - len(shipped)
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.75)
    raise FileNotFoundError(
        f"no configuration {str(name_or_path)!r}: not a file, and not a packaged configuration"
        + (f"; did you mean {' or '.join(close)}?" if close else "")
        + f" (shipped: {', '.join(shipped)}"
        + (f"; and {records} experiment records, experimental/NAME for experiments/NAME.yaml)"
           if records else ")")
    )  # fmt: skip


def _read_yaml(path: str | Path) -> dict[str, Any]:
    """The YAML document of a configuration file; a malformed or empty file is a
    :class:`ConfigError` naming the file (an empty file would silently mean "every default")."""
    try:
        with open(path, encoding="utf-8") as handle:
            data = yaml.safe_load(handle)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{path} is not valid YAML{where}: {problem}") from exc
    if data is None:
        raise ConfigError(
            f"{path} is empty; a configuration must set at least one key (to train with the "
            f"default recipe, leave out --config: it is {DEFAULT_CONFIG})"
        )
    if not isinstance(data, dict):
        raise ConfigError(f"{path} must hold a mapping of keys, got {type(data).__name__}")
    return data


#: Settings that name a file, as their keys from the top: a relative path is read beside the
#: configuration file that names it when a file is there, else from the working directory
#: (as ``base``), so that a recipe and its file load from any directory.
FILE_SETTINGS = (("traffic", "go_model"), ("env", "episode", "go_model"))


def _files_beside(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """``data`` (changed in place) with each :data:`FILE_SETTINGS` path found beside ``path``
    made absolute."""
    for inner, keys, value in named_files(data):
        found = path.parent / value
        if not Path(value).is_absolute() and found.is_file():
            inner[keys[-1]] = str(found.resolve())
    return data


def named_files(data: dict[str, Any]) -> list[tuple[dict[str, Any], tuple[str, ...], str]]:
    """Each :data:`FILE_SETTINGS` setting of the configuration mapping ``data`` that names a
    file: ``(the mapping holding it, its keys from the top, its value)``."""
    found: list[tuple[dict[str, Any], tuple[str, ...], str]] = []
    for keys in FILE_SETTINGS:
        inner: Any = data
        for key in keys[:-1]:
            inner = inner.get(key) if isinstance(inner, dict) else None
        if isinstance(inner, dict) and isinstance(inner.get(keys[-1]), str):
            found.append((inner, keys, inner[keys[-1]]))
    return found


def write_config_with_files(folder: str | Path, config_text: str) -> None:
    """``folder/config.yaml`` (``config_text``, a resolved configuration) with every file a
    setting names (:data:`FILE_SETTINGS`, e.g. ``episode.go_model``) copied beside it and
    named there by its file name, so that a run or policy folder is whole: it loads (``read
    beside``) wherever it is moved. Each file is written whole (``replacing``).

    Raises:
        ConfigError: Two settings name different files of one name, or the folder holds
            another file of that name already.
    """
    from safeswitch.io import replacing, write_atomic  # writing a run, not reading a config

    folder = Path(folder)
    data = yaml.safe_load(config_text)
    named = named_files(data)
    if not named:  # the text as given, byte for byte
        write_atomic(folder / "config.yaml", config_text)
        return
    copied: dict[str, Path] = {}
    for inner, keys, value in named:
        source = Path(value)
        target = folder / source.name
        if source.resolve() != target.resolve():
            other = copied.get(source.name)
            if (other is not None and other != source.resolve()) or (
                other is None and target.exists()
                and target.read_bytes() != source.read_bytes()
            ):  # fmt: skip
                raise ConfigError(
                    f"{'.'.join(keys)}={value!r}: {folder} holds another {source.name!r} already"
                )
            with replacing(target) as tmp:
                shutil.copyfile(source, tmp)
        copied[source.name] = source.resolve()
        inner[keys[-1]] = source.name
    write_atomic(folder / "config.yaml", yaml.safe_dump(data, sort_keys=False))


def comparable(config: Any) -> Any:
    """``config`` (a dataclass) as a mapping in which each file a setting names
    (:data:`FILE_SETTINGS`) is its contents' SHA-256, not its path: two runs of one recipe
    compare equal wherever each keeps its copy of the file."""
    data = to_dict(config)
    for inner, keys, value in named_files(data):
        path = Path(value)
        inner[keys[-1]] = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else value
    return data


#: The key with which a configuration names the one it changes (see :func:`read_config`).
BASE_KEY = "base"


def read_config(path: str | Path, _chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The mapping of a configuration file with its ``base`` resolved.

    A configuration may start from another: ``base: NAME`` (a packaged configuration's name,
    or a path, relative to the file that names it or to the working directory) takes every
    value of that one, and this file's values replace its values mapping by mapping — a
    nested mapping changes only the keys it names, anything else (a number, a list, ``null``,
    an empty mapping) replaces the base's value whole. Bases may have bases. A setting that
    names a file (:data:`FILE_SETTINGS`, e.g. ``traffic.go_model``) is read the same way:
    beside the file that names it, else from the working directory.

    Raises:
        ConfigError: ``base`` is not a string, names no configuration, or the chain of bases
            comes back to a file already in it (each names the file and the value).
    """
    path = Path(path)
    # each file in the layout of today before the merge: a file written before the ``ppo``
    # split may start from one written after it
    data = _files_beside(move_keys(_read_yaml(path), MOVED_FROM_PPO, str(path)), path)
    base = data.pop(BASE_KEY, None)
    if base is None:
        return data
    if not isinstance(base, str) or not base:
        raise ConfigError(f"{path}: {BASE_KEY} must name a configuration, got {base!r}")
    beside = path.parent / base
    try:
        base_path = beside if beside.is_file() else config_path(base)
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: {BASE_KEY} {base!r}: {exc}") from exc
    chain = (*_chain, path.resolve())
    if base_path.resolve() in chain:
        names = " -> ".join(str(p) for p in (*chain, base_path.resolve()))
        raise ConfigError(f"{path}: {BASE_KEY} {base!r} comes back to itself ({names})")
    return _merged(read_config(base_path, chain), data, BASE_KEY)


def load_config(path: str | Path) -> TrainConfig:
    """A :class:`TrainConfig` from a YAML file or a packaged name (missing keys keep their
    defaults; ``base:`` starts from another configuration, see :func:`read_config`)."""
    path = config_path(path)
    return from_dict(TrainConfig, read_config(path), where="")


def dump_config(config: TrainConfig) -> str:
    """The configuration as YAML (every value, defaults included)."""
    return yaml.safe_dump(to_dict(config), sort_keys=False)


@dataclass(frozen=True)
class EnvTrainConfig:
    """A training run on a registered Gymnasium environment.

    Attributes:
        env_id: The Gymnasium id (``module:EnvId`` imports ``module`` first, as
            ``gymnasium.make`` does; a resumed or evaluated run imports it again).
        switching: A registered switching logic (``None``: the environment's default).
        logic_params: Parameters of that logic, for one registered with the class of its
            parameters (e.g. ``ttc``: ``{min_ttc: 2.0}``); ``null``: its defaults.
        penalty: The reward added on a step the Safety controller acted (``None``: the
            environment's default, or -25 — the paper's ``R_ADAS`` — for a wrapped one).
        env_kwargs: Further keyword arguments of ``gymnasium.make``.
        timesteps: Environment steps to train for, summed over environments.
        n_envs: Environments (SB3 ``DummyVecEnv``).
        seed: Seed of PPO, the networks and the environments.
        torch_threads: CPU threads torch may use.
        checkpoint_every: Save a resumable checkpoint every this many timesteps.
        eval_episodes: Episodes of the final evaluation.
        eval_seed: Seed of the final evaluation's episodes (never used in training).
        ppo: PPO hyper-parameters: Table II's with the left turn's step size, GAE λ and epochs
            by default, one section for every plant (:class:`EnvPPOConfig`).
        policy: How the policy and its optimiser depart from Table II (ours); unlike the left
            turn's, learning from the interventions is on by default (:class:`EnvPolicyConfig`).
        constraints: Constrained PPO (ours): cost name → its constraint. A name is a cost the
            plant publishes per step in ``info["costs"]`` (e.g. ``speeding``), measured as its
            mean per step; two are the switch's own: ``intervention``, the share of steps on
            which the safety action ran, and ``safety``, the share of episodes with one. See
            :class:`~safeswitch.training.constraints.NamedCostConstraints`.
        validation: Best-policy selection on validation episodes (off by default): every
            ``every`` timesteps the deterministic policy drives ``episodes`` episodes reset
            with seeds from ``seed``; ``criterion`` ``return`` keeps the highest mean return,
            ``collisions_then_return`` the fewest failures first (as the plant declares
            them). ``switching``, ``stress`` and ``constraints_then_return`` are the left
            turn's.
    """

    env_id: str
    switching: str | None = None
    logic_params: dict[str, Any] | None = None
    penalty: float | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    timesteps: Annotated[int, Bounds(1)] = 100_000
    n_envs: Annotated[int, Bounds(1)] = 4
    seed: Annotated[int, Bounds(0, SEED_MAX)] = 0
    torch_threads: Annotated[int, Bounds(1)] = 1
    checkpoint_every: Annotated[int, Bounds(1)] = 20_000
    eval_episodes: Annotated[int, Bounds(0)] = 20
    eval_seed: Annotated[int, Bounds(0, SEED_MAX)] = 1_000_003
    ppo: EnvPPOConfig = field(default_factory=EnvPPOConfig)
    policy: EnvPolicyConfig = field(default_factory=EnvPolicyConfig)
    constraints: dict[str, ConstraintConfig] = field(default_factory=dict)
    validation: ValidationConfig = field(default_factory=ValidationConfig)

    MOVED: ClassVar[dict[str, str]] = {
        k: v for k, v in MOVED_FROM_PPO.items() if v.startswith("policy.")
    }

    def __post_init__(self) -> None:
        o = "train"
        check_bounds(self, o)
        try:
            registered = plain_env_id(self.env_id) in gym.registry
        except ModuleNotFoundError as exc:
            raise ConfigError(f"env_id={self.env_id!r}: {exc}") from exc
        if not registered:
            raise ConfigError(
                f"env_id={self.env_id!r} is not a registered Gymnasium id (a user's environment: "
                "'module:EnvId', or --import the module that registers it)"
            )
        if self.switching is not None and self.switching not in logic_names():
            raise ConfigError(
                f"switching={self.switching!r} is not a registered switching logic "
                f"(known: {', '.join(logic_names())})"
            )
        if self.logic_params:
            if self.switching is None:
                raise ConfigError("logic_params need switching: the logic they configure")
            logic_params(self.switching, self.logic_params, "logic_params")
        if self.penalty is not None:
            check(math.isfinite(self.penalty) and self.penalty <= 0, o, "penalty", self.penalty,
                  "must be a finite number <= 0 (a bonus for needing the Safety controller "
                  "would teach the policy to need it)")  # fmt: skip
        check_run_shape(self.n_envs, self.ppo)
        v = self.validation
        for name, value, why in (
            ("switching", v.switching, "a plant is validated under its own logic"),
            ("stress", v.stress, "stress sets are scenario sets of the left turn"),
            ("families", v.families or None, "traffic families are the left turn's"),
            ("scenes", v.scenes or None, "validation scenes are the left turn's"),
        ):
            check(value is None, "validation", name, value, f"must be null ({why})")
        check(v.criterion != "constraints_then_return", "validation", "criterion", v.criterion,
              "must be return or collisions_then_return on a plant (constraints_then_return "
              "ranks by the left turn's measures)")  # fmt: skip
        for name, given in self.constraints.items():
            check(isinstance(given, ConstraintConfig), "constraints", name, given,
                  "must be a constraint (budget, gains, …)")  # fmt: skip
            check(not given.reasons, f"constraints.{name}", "reasons", given.reasons,
                  "are the left turn's (a plant's costs come from info['costs'])")  # fmt: skip
        for name in ("intervention", "safety"):
            if name in self.constraints:
                budget = self.constraints[name].budget
                check(budget < 1, f"constraints.{name}", "budget", budget,
                      "is a share: must be < 1")  # fmt: skip

    @property
    def batch_size(self) -> int:
        return self.ppo.n_steps * self.n_envs // self.ppo.n_minibatches


def load_env_config(path: str | Path) -> EnvTrainConfig:
    """An :class:`EnvTrainConfig` from YAML (``base:`` as for :func:`read_config`)."""
    return from_dict(EnvTrainConfig, read_config(config_path(path)))


def dump_env_config(config: EnvTrainConfig) -> str:
    return yaml.safe_dump(to_dict(config), sort_keys=False)


def load_any_config(path: str | Path) -> TrainConfig | EnvTrainConfig:
    """A run's configuration: an :class:`EnvTrainConfig` if it names an ``env_id``, else the
    left turn's :class:`TrainConfig`."""
    path = config_path(path)
    data = read_config(path)
    if isinstance(data, dict) and "env_id" in data:
        return from_dict(EnvTrainConfig, data)
    return from_dict(TrainConfig, data)
