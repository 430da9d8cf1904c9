"""Training of one world model (Baseline, State-GRU-WM, AC-GRU-WM, Linear-ARX, AC-MLP-WM or
the causal Transformer W_T) on a built dataset: :func:`train` (``rmi train-wm``).

The run directory gets config.json (model architecture, training settings, data path, size,
state groups, shuffle flag and the dataset's standardisation statistics), model.safetensors
(selected weights), metrics.jsonl (per epoch: the training loss, the validation loss of
free rollouts and the validation rollout errors; see :mod:`rmi_learn.metrics_log`),
summary.json and, for gradient-trained models, train_state.pt for ``resume`` (and with
``tensorboard``, TensorBoard events). Load the result with
``rmi_learn.world_models.load(RUN)``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rmi_learn.data.schema import HORIZON
from rmi_learn.errors import input_errors
from rmi_learn.metrics_log import (
    METRICS_FILE,
    TENSORBOARD_DIR,
    TensorBoardLog,
    require_tensorboard,
)
from rmi_learn.sensing import SensorModel, check_observation_mode
from rmi_learn.world_models.training_settings import (
    DEBUG_TRAIN_WINDOWS,
    DEBUG_VAL_WINDOWS,
    DEFAULTS,
    HUBER_DELTA,
    LOSS_SCALES,
    MODEL_CHOICES,
    RESUME_FIXED,
    RESUME_LEGACY,
    select_metric,
)

if TYPE_CHECKING:
    from rmi_learn.data.dataset import Dataset

# torch, and the modules that import it (the data set tries to), are imported inside the
# functions: the pipeline imports this module to describe its training stages on an install
# without torch.


def debug_subset(ws: Any, n: int, seed: int) -> Any:
    """At most ``n`` windows of ``ws``, drawn by ``seed`` (debug mode)."""
    from rmi_learn.world_models.common import Subset

    if len(ws) <= n:
        return ws
    idx = np.sort(np.random.default_rng([seed, 17]).choice(len(ws), n, replace=False))
    return Subset(ws, idx)


@input_errors(ValueError, TypeError)
def train(
    model: str,
    data: str | Path,
    out: str | Path,
    *,
    size_cm: int | None = None,
    state_groups: str = "ALL",
    shuffle_actions: bool = False,
    epochs: int = 40,
    patience: int | None = 8,
    tf_epochs: int = 20,
    batch_size: int = 128,
    steps_per_epoch: int | None = None,
    water_weight: float | None = None,
    huber_delta: float = HUBER_DELTA,
    loss_scale: str | None = None,
    lr: float | None = None,
    val_windows: int | None = 4096,
    seed: int = 0,
    deterministic: bool = False,
    device: str = "cpu",
    resume: bool = False,
    debug: bool = False,
    progress: bool = True,
    model_args: dict[str, Any] | None = None,
    tensorboard: bool = False,
    horizon: int | None = None,
    observation_mode: str = "privileged",
    sensors: SensorModel | None = None,
    val_phases: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Train one world model into ``out`` and return the run summary (see module doc).

    Gradient-trained models use :class:`rmi_learn.trainer.Trainer` with the world-model loss
    (gamma 0.98, lambda_c = lambda_f = 0.2; Transformer: water weight 8), teacher forcing
    decaying linearly from 1 to 0 over ``tf_epochs`` epochs for the recurrent decoders (whose
    early-stopping patience counts only epochs after that decay), and checkpoint selection on
    validation free-rollout water MAE (g) at 1.28 s (Transformer: mean over
    0.16/0.32/0.64/1.28 s). The learned models predict each channel's change in units
    of its step-to-step RMS change in the training windows
    (:meth:`~rmi_learn.world_models.common.WorldModel.set_delta_scale`, recorded in the
    model's config). Linear-ARX is fitted in closed form; the Baseline only
    writes its config. ``model_args`` overrides constructor arguments (e.g. ``hidden``,
    ``d_model``); an unknown name raises TypeError. ``horizon``: the forecast length of the
    training and validation windows in control steps (default: a lookahead model's fixed
    horizon, else 64); a model that ranks 32-step chunks can learn from 32-step windows,
    of which a run has more. ``huber_delta`` is the Huber threshold
    in standardised units (default 1). ``loss_scale="change"`` (default for the GRU and
    MLP models; ``"state"``, the paper's, for the Transformer) measures each continuous
    channel's error in units of its RMS change over the horizon in the training windows
    (:func:`rmi_learn.world_models.common.change_scale`, stored in config.json as
    ``channel_scale``) before the Huber loss and the water weight. ``resume`` refuses
    settings of :data:`RESUME_FIXED` that differ from the first call's. Every epoch's
    metrics go to ``metrics.jsonl``, among them ``val_loss``: the training loss on the
    validation windows' free rollouts (no teacher forcing, the same weights and scale);
    ``tensorboard`` also writes them as TensorBoard events (needs ``tensorboard``).
    ``observation_mode="sensors"`` trains on histories of what the gripper's sensors report
    under ``sensors`` (default: :class:`~rmi_learn.sensing.SensorModel`'s defaults; see
    :meth:`~rmi_learn.data.dataset.Dataset.windows`) toward the same y_t targets; the model
    then estimates y_t from them (the GRU models only), and config.json records the mode
    and the sensor model. ``val_phases`` (e.g. ``("squeeze",)``) validates, and so chooses
    the checkpoint, on the validation windows anchored in those phases only.

    Settings or data it cannot train on (an unknown model or constructor argument, no
    training windows, a resume with other settings) raise
    :class:`~rmi_learn.errors.InputError`.
    """
    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.trainer import seed_everything

    _check_request(model, state_groups, loss_scale, tensorboard)
    sensing = _sensing(model, observation_mode, sensors)
    out = Path(out)
    ds = load_dataset(data)
    stats = ds.stats
    seed_everything(seed, deterministic)
    if sensing is not None and "weight_reading" not in (model_args or {}):
        # The estimate of the water starts from what the wrist load weighs
        # (``--model-arg weight_reading=null`` leaves it to the estimate head alone).
        from rmi_learn.world_models.weight_persistence import weight_reading

        reading = list(weight_reading(ds, sensing))
        model_args = {**(model_args or {}), "weight_reading": reading}
    net = _build_model(model, state_groups, model_args, observation_mode)
    horizon = _window_horizon(net, model, horizon)
    train_ws, val_ws = _window_sets(
        ds, data, size_cm, horizon, shuffle_actions, debug, seed, sensing, val_phases
    )
    if debug:
        tf_epochs = 1
        batch_size = min(batch_size, 8)
    extra = _extra_config(
        data, size_cm, state_groups, shuffle_actions, seed, debug, ds, train_ws, val_ws
    )
    extra.update(_sensing_config(ds, sensing, val_phases))
    if not net.trainable:
        validate = _validation(val_ws, stats.z_std, horizon, val_windows, device, None)
        return _closed_form(net, model, out, train_ws, validate, extra, resume, tensorboard)
    _set_delta_scale(net, train_ws)
    d = DEFAULTS[model]
    extra["tf_epochs"] = tf_epochs
    if water_weight is None:
        water_weight = float(d.get("water_weight", 1.0))
    extra["water_weight"] = water_weight
    extra["huber_delta"] = huber_delta
    if loss_scale is None:
        loss_scale = str(d.get("loss_scale", "state"))
    extra["loss_scale"] = loss_scale
    loss_fn, rollout_loss = _losses(net, train_ws, extra, tf_epochs)
    validate = _validation(val_ws, stats.z_std, horizon, val_windows, device, rollout_loss)
    cfg = _train_config(
        net,
        d,
        horizon=horizon,
        epochs=epochs,
        batch_size=batch_size,
        steps_per_epoch=steps_per_epoch,
        lr=lr,
        patience=patience,
        tf_epochs=tf_epochs,
        seed=seed,
        deterministic=deterministic,
        device=device,
        debug=debug,
        progress=progress,
    )
    return _fit(net, loss_fn, train_ws, out, cfg, validate, extra, resume, tensorboard)


def _check_request(
    model: str, state_groups: str, loss_scale: str | None, tensorboard: bool
) -> None:
    """Refuse an unknown model or loss scale and state groups for a model without them
    (ValueError); check that TensorBoard is installed when asked for."""
    if model not in MODEL_CHOICES:
        raise ValueError(f"unknown model {model!r}")
    if tensorboard:
        require_tensorboard()
    if loss_scale is not None and loss_scale not in LOSS_SCALES:
        raise ValueError(f"loss_scale must be one of {list(LOSS_SCALES)}, got {loss_scale!r}")
    if model in ("baseline", "arx") and state_groups != "ALL":
        raise ValueError(f"--state-groups applies to learned models, not {model}")


def _sensing(model: str, observation_mode: str, sensors: SensorModel | None) -> SensorModel | None:
    """The sensor model of a sensor-mode training (None for y_t); ValueError naming the
    field for a mode or a model the sensors mode does not take (the model itself refuses
    state groups other than ALL)."""
    from rmi_learn.world_models.registry import SENSOR_MODEL_KINDS

    check_observation_mode(observation_mode)
    if observation_mode == "privileged":
        if sensors is not None:
            raise ValueError("sensors applies to observation_mode 'sensors' only")
        return None
    if model not in SENSOR_MODEL_KINDS:
        raise ValueError(
            f"observation_mode 'sensors' is taken by {', '.join(SENSOR_MODEL_KINDS)}, "
            f"not {model} (it reads y_t)"
        )
    return SensorModel() if sensors is None else sensors


def _build_model(
    model: str,
    state_groups: str,
    model_args: dict[str, Any] | None,
    observation_mode: str = "privileged",
) -> Any:
    """The untrained network of ``model`` with ``model_args`` and, for a learned model, its
    state groups and (in the sensors mode) its observation mode."""
    from rmi_learn.world_models import build

    kw: dict[str, Any] = {"kind": model, **(model_args or {})}
    if model != "baseline" and model != "arx":
        kw["state_groups"] = state_groups
    if observation_mode != "privileged":
        kw["observation_mode"] = observation_mode
    return build(kw)


def _window_horizon(net: Any, model: str, horizon: int | None) -> int:
    """The forecast length of the windows: ``horizon``, else the model's fixed horizon,
    else the dataset default; ValueError when it contradicts a fixed horizon."""
    # A lookahead model of a fixed horizon (e.g. --model-arg horizon=32, to score the
    # policies' chunks) learns from windows of that horizon.
    fixed = getattr(net, "fixed_horizon", None)
    if horizon is None:
        horizon = fixed or HORIZON
    if horizon < 1 or (fixed is not None and horizon != fixed):
        raise ValueError(
            f"horizon {horizon}: must be >= 1"
            + (f" and equal the {model} model's fixed horizon {fixed}" if fixed else "")
        )
    return horizon


def _window_sets(
    ds: Dataset,
    data: str | Path,
    size_cm: int | None,
    horizon: int,
    shuffle_actions: bool,
    debug: bool,
    seed: int,
    sensing: SensorModel | None = None,
    val_phases: Sequence[str] | None = None,
) -> tuple[Any, Any]:
    """The training and validation windows (histories of the sensors under ``sensing``,
    else y_t): with ``shuffle_actions`` each history paired with another run's chunk, in
    debug mode a small subset of each."""
    from rmi_learn.world_models.common import ShuffledActions

    mode = "privileged" if sensing is None else "sensors"
    kw: dict[str, Any] = {"horizon": horizon, "observation_mode": mode, "sensors": sensing}
    train_ws: Any = ds.windows("train", size_cm=size_cm, **kw)
    val_ws: Any = ds.windows("val", size_cm=size_cm, anchor_phases=val_phases, **kw)
    if len(train_ws) == 0:
        raise ValueError(f"no training windows in {data} (size {size_cm})")
    if val_phases is not None and len(val_ws) == 0:
        raise ValueError(f"val_phases {list(val_phases)}: no validation windows in {data}")
    if shuffle_actions:
        train_ws = ShuffledActions(train_ws, seed=seed)
        val_ws = ShuffledActions(val_ws, seed=seed + 1)
    if debug:
        train_ws = debug_subset(train_ws, DEBUG_TRAIN_WINDOWS, seed)
        val_ws = debug_subset(val_ws, DEBUG_VAL_WINDOWS, seed)
    return train_ws, val_ws


def _extra_config(
    data: str | Path,
    size_cm: int | None,
    state_groups: str,
    shuffle_actions: bool,
    seed: int,
    debug: bool,
    ds: Dataset,
    train_ws: Any,
    val_ws: Any,
) -> dict[str, Any]:
    """What config.json records of the data beside the model and optimiser settings."""
    return {
        "data": str(Path(data).resolve()),
        "size_cm": size_cm,
        "state_groups": state_groups,
        "shuffle_actions": shuffle_actions,
        "seed": seed,
        "debug": debug,
        "history": train_ws.history if hasattr(train_ws, "history") else None,
        "horizon": train_ws.horizon if hasattr(train_ws, "horizon") else None,
        "n_train": len(train_ws),
        "n_val": len(val_ws),
        "stats": ds.stats.to_json(),
    }


def _sensing_config(
    ds: Dataset, sensing: SensorModel | None, val_phases: Sequence[str] | None
) -> dict[str, Any]:
    """What config.json records of the observation mode and the validation phases; in the
    sensors mode also how the model's inputs are standardised (``sensor_stats``), for a
    caller that feeds it online."""
    out: dict[str, Any] = {
        "val_phases": None if val_phases is None else list(val_phases),
        "observation_mode": "privileged" if sensing is None else "sensors",
        "sensors": None if sensing is None else sensing.as_dict(),
    }
    if sensing is not None:
        from rmi_learn.data.dataset.sensor_view import SENSOR_INPUTS

        view = ds.sensor_view(sensing)
        out["sensor_stats"] = {
            "names": list(SENSOR_INPUTS),
            "mean": view.mean.tolist(),
            "std": view.std.tolist(),
        }
    return out


def _validation(
    val_ws: Any, z_std: Any, horizon: int, val_windows: int | None, device: str, loss: Any
) -> Any:
    """The per-epoch validation: free-rollout metrics of the validation windows (with
    ``loss``, also the training loss on those rollouts), prefixed ``val_``."""
    from rmi_learn.world_models.evaluation import evaluate_rollouts

    def validate(m: Any, state: Any = None) -> dict[str, float]:
        if len(val_ws) == 0:
            return {
                select_metric("val_water_mae_g@64", horizon): float("nan"),
                "val_water_mae_g_mean": float("nan"),
            }
        r = evaluate_rollouts(m, val_ws, z_std, max_windows=val_windows, device=device, loss=loss)
        return {f"val_{k}": v for k, v in r.items()}

    return validate


def _set_delta_scale(net: Any, train_ws: Any) -> None:
    """Give ``net``'s predicted changes the unit of each channel's step-to-step change in
    the training windows (:func:`rmi_learn.world_models.common.step_scale`); config.json
    records it with the architecture (a resume of a run trained without it is refused as
    another model)."""
    from rmi_learn.world_models.common import step_scale

    net.set_delta_scale(step_scale(train_ws))


def _losses(net: Any, train_ws: Any, extra: dict[str, Any], tf_epochs: int) -> tuple[Any, Any]:
    """The training loss (with teacher forcing decaying over ``tf_epochs`` for recurrent
    models) and the same loss of free rollouts, weighted and scaled as ``extra`` says; a
    change scale is measured on ``train_ws`` and recorded in ``extra``."""
    import torch

    from rmi_learn.world_models.common import N_Z, WATER, change_scale, wm_loss

    huber_delta = extra["huber_delta"]
    cw = torch.ones(N_Z)
    cw[WATER] = extra["water_weight"]
    scale = None
    if extra["loss_scale"] == "change":
        # Targets and histories do not depend on the pairing of chunks, so shuffled and
        # debug subsets give the scale of the windows they train on.
        scale = change_scale(train_ws)
        extra["channel_scale"] = [float(v) for v in scale]

    def loss_fn(m: Any, batch: dict[str, torch.Tensor], state: Any) -> Any:
        tf = max(0.0, 1.0 - state.epoch / tf_epochs) if (m.recurrent and tf_epochs > 0) else 0.0
        o = m(
            batch["hist"],
            batch["hist_mask"],
            batch["actions"],
            teacher=batch if tf > 0 else None,
            tf_prob=tf,
        )
        loss, logs = weighted_loss(m, o, batch)
        logs["tf_prob"] = tf
        return loss, logs

    def weighted_loss(m: Any, o: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]) -> Any:
        """The training loss of ``m``'s outputs ``o``: (loss, logs)."""
        return wm_loss(
            o,
            batch,
            channel_weight=cw.to(o["z"].device),
            channel_scale=None if scale is None else scale.to(o["z"].device),
            z_keep=m.z_keep,
            classify=m.classify,
            huber_delta=huber_delta,
        )

    def rollout_loss(o: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]) -> Any:
        return weighted_loss(net, o, batch)[0]

    return loss_fn, rollout_loss


def _train_config(
    net: Any,
    d: dict[str, Any],
    *,
    horizon: int,
    epochs: int,
    batch_size: int,
    steps_per_epoch: int | None,
    lr: float | None,
    patience: int | None,
    tf_epochs: int,
    seed: int,
    deterministic: bool,
    device: str,
    debug: bool,
    progress: bool,
) -> Any:
    """The optimisation settings of a gradient-trained model (``d``: its defaults)."""
    from rmi_learn.trainer import TrainConfig

    return TrainConfig(
        epochs=epochs,
        batch_size=batch_size,
        max_steps_per_epoch=steps_per_epoch,
        lr=lr if lr is not None else d["lr"],
        optimizer=d["optimizer"],
        weight_decay=d.get("weight_decay", 0.0),
        grad_clip=1.0,
        patience=patience,
        # Early stopping and selection wait for the end of the teacher-forcing decay: before
        # it, the free-rollout validation metric judges a model still trained on fed targets.
        min_epochs=tf_epochs if net.recurrent else 0,
        select_after=tf_epochs if net.recurrent else 0,
        select_metric=select_metric(d["select"], horizon),
        select_mode="min",
        seed=seed,
        deterministic=deterministic,
        device=device,
        debug=debug,
        progress=progress,
    )


def _fit(
    net: Any,
    loss_fn: Any,
    train_ws: Any,
    out: Path,
    cfg: Any,
    validate: Any,
    extra: dict[str, Any],
    resume: bool,
    tensorboard: bool,
) -> dict[str, Any]:
    """Train with the shared loop; the summary gains the parameter count and wall time."""
    from rmi_learn.trainer import Trainer, count_parameters

    trainer = Trainer(
        net,
        loss_fn,
        train_ws,
        out,
        cfg,
        evaluate=validate,
        model_config=net.config(),
        extra_config=extra,
        resume=resume,
        resume_fixed=RESUME_FIXED,
        resume_legacy=RESUME_LEGACY,
        tensorboard=tensorboard,
    )
    t0 = time.perf_counter()
    summary = trainer.fit()
    summary["params"] = count_parameters(net)
    summary["wall_s"] = time.perf_counter() - t0
    return summary


def _closed_form(
    net: Any,
    model: str,
    out: Path,
    train_ws: Any,
    validate: Any,
    extra: dict[str, Any],
    resume: bool,
    tensorboard: bool = False,
) -> dict[str, Any]:
    """Baseline (nothing to fit) and Linear-ARX (ridge): same run-directory layout, one
    ``epoch`` line of validation metrics (no training loss)."""
    from rmi_learn.trainer import BEST_WEIGHTS, CONFIG_FILE, SUMMARY_FILE, save_weights, write_json

    if (out / CONFIG_FILE).exists():
        if not resume:
            raise FileExistsError(
                f"{out} already holds a run; pass --resume to continue it or choose another "
                "output directory"
            )
        if (out / SUMMARY_FILE).exists():
            done: dict[str, Any] = json.loads((out / SUMMARY_FILE).read_text(encoding="utf-8"))
            return done
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if model == "arx":
        extra["n_fit"] = net.fit(train_ws)
    write_json(
        out / CONFIG_FILE,
        {
            "model": net.config(),
            "train": None,
            "extra": extra,
            "params": 0,
            "train_size": len(train_ws),
        },
    )
    save_weights(net.state_dict(), out / BEST_WEIGHTS)
    metrics = validate(net)
    fit_s = time.perf_counter() - t0
    record = {"kind": "epoch", "epoch": 1, "step": 0, "fit_s": fit_s, **metrics}
    with open(out / METRICS_FILE, "a", encoding="utf-8") as f:
        f.write(json.dumps(record) + "\n")
    if tensorboard:
        log = TensorBoardLog(out / TENSORBOARD_DIR)
        log.write(record)
        log.close()
    summary = {
        "finished": True,
        "stopped_early": False,
        "epochs": 1,
        "steps": 0,
        "select_metric": select_metric("val_water_mae_g@64", train_ws.horizon),
        "best_metric": metrics.get(select_metric("val_water_mae_g@64", train_ws.horizon)),
        "best_epoch": 1,
        "params": 0,
        "wall_s": fit_s,
    }
    write_json(out / SUMMARY_FILE, summary)
    return summary
