"""``rmi train-wm``: train one world model on a built dataset (see
:mod:`rmi_learn.world_models.training`).

    rmi train-wm --model ac-gru --data DATASET --out RUN [--size 8|10|12]
                 [--state-groups LS|LS+G|LS+G+C|ALL] [--shuffle-actions]
                 [--observation-mode privileged|sensors] [--sensors JSON] [--epochs N]
                 [--water-weight W] [--huber-delta D] [--loss-scale state|change]
                 [--seed S] [--resume] [--debug] [--config FILE] [--tensorboard]

``--config FILE`` holds any of these options as JSON (see
:mod:`rmi_learn.cli.options_file`); options on the command line override it.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from rmi_learn.cli.options_file import add_config_option
from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.data.schema import LEARNING_PHASES, SPONGE_SIZES_CM
from rmi_learn.errors import InputError
from rmi_learn.option_types import count, device, positive, seed
from rmi_learn.sensing import OBSERVATION_MODES, SensorModel
from rmi_learn.world_models.training_settings import (
    GROUP_CHOICES,
    HUBER_DELTA,
    LOSS_SCALES,
    MODEL_CHOICES,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi train-wm``."""
    parser.add_argument("--model", required=True, choices=MODEL_CHOICES, help="forecaster")
    parser.add_argument("--data", required=True, metavar="DIR", help="built dataset directory")
    parser.add_argument("--out", required=True, metavar="DIR", help="run output directory")
    parser.add_argument(
        "--size",
        type=int,
        choices=SPONGE_SIZES_CM,
        default=None,
        help="train on one sponge size (cm) (default: all sizes)",
    )
    parser.add_argument(
        "--state-groups",
        default="ALL",
        choices=GROUP_CHOICES,
        help="observation channels the model sees: LS (the water: retained mass, saturation, "
        "pore and sponge volume), +G (gripper width and forces), +C (contact and friction), "
        "ALL (also the residual slip speed)",
    )
    parser.add_argument(
        "--shuffle-actions",
        action="store_true",
        help="pair each history with an action chunk from another run",
    )
    parser.add_argument(
        "--observation-mode",
        default="privileged",
        choices=OBSERVATION_MODES,
        help="what the model's history holds: privileged (y_t) or sensors (what the "
        "gripper's width, pad, tactile and wrist force/torque sensors report, with noise "
        "and latency, and the dry sponge's mass; GRU models only); the forecast targets "
        "are y_t's in either mode",
    )
    parser.add_argument(
        "--sensors",
        type=_sensor_model,
        default=None,
        metavar="JSON",
        help="the sensors' noise and latency as a JSON object of SensorModel's fields, e.g. "
        '\'{"wrist_N": 0.1, "latency_ticks": 2}\' (default: the defaults of '
        "docs/control.md: wrist 0.06 N, pads 0.5 N, one control step of latency)",
    )
    parser.add_argument(
        "--model-arg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="architecture override passed to the model constructor, e.g. d_model=128 "
        "(JSON value; repeatable) (default: each model's standard architecture)",
    )
    parser.add_argument(
        "--horizon",
        type=count(1),
        default=None,
        help="forecast steps of the training windows (default: a lookahead model's fixed "
        "horizon, else 64; 32 to learn to score the policies' chunks)",
    )
    parser.add_argument("--epochs", type=count(1), default=40, help="maximum epochs")
    parser.add_argument(
        "--patience", type=count(1), default=8, help="early-stopping patience (epochs)"
    )
    parser.add_argument(
        "--tf-epochs",
        type=count(0),
        default=20,
        help="teacher forcing decays 1 -> 0 over this many epochs",
    )
    parser.add_argument(
        "--water-weight",
        type=positive,
        default=None,
        help="loss weight of the retained-water channel (default: 8 for the Transformer, "
        "1 otherwise)",
    )
    parser.add_argument(
        "--huber-delta",
        type=positive,
        default=HUBER_DELTA,
        help="Huber loss threshold in standardised units (torch's): errors above it are "
        "weighed linearly, below it quadratically",
    )
    parser.add_argument(
        "--loss-scale",
        choices=LOSS_SCALES,
        default=None,
        help="state: errors in units of each channel's standardised level; change: in units "
        "of each channel's RMS change over the horizon in the training windows, so that "
        "slowly moving channels such as retained water count (default: state for the "
        "Transformer, change for the GRU and MLP models)",
    )
    parser.add_argument("--batch-size", type=count(1), default=128, help="windows per batch")
    parser.add_argument(
        "--steps-per-epoch",
        type=count(1),
        default=None,
        help="cap the optimiser steps per epoch (each epoch then sees a fresh random subset "
        "of the windows) (default: every window once)",
    )
    parser.add_argument(
        "--lr", type=positive, default=None, help="learning rate (default: the model's)"
    )
    parser.add_argument(
        "--val-windows",
        type=count(1),
        default=4096,
        help="validate on at most this many evenly spaced windows",
    )
    parser.add_argument(
        "--val-phases",
        nargs="+",
        choices=LEARNING_PHASES,
        default=None,
        metavar="PHASE",
        help="validate, and choose the checkpoint, on the validation windows anchored in these "
        f"phases only ({', '.join(LEARNING_PHASES)}; e.g. squeeze, where the sponge is "
        "lifted and the goal-reaching benchmark acts) (default: every validation window)",
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of initialisation and draws")
    parser.add_argument(
        "--deterministic", action="store_true", help="use torch's deterministic algorithms only"
    )
    parser.add_argument("--device", type=device, default="cpu", help="torch device")
    add_threads(parser, "torch")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    parser.add_argument("--debug", action="store_true", help="tiny run that takes seconds")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_tensorboard_option(parser)
    add_config_option(parser)


#: ``--config FILE`` holds this command's options (see :mod:`rmi_learn.cli.options_file`).
OPTIONS_FILE = True


def add_tensorboard_option(parser: argparse.ArgumentParser) -> None:
    """``--tensorboard``, shared by the training commands."""
    parser.add_argument(
        "--tensorboard",
        action="store_true",
        help="also write the metrics as TensorBoard events to OUT/tensorboard (needs the "
        "tensorboard package); OUT/metrics.jsonl is always written",
    )


def run(args: argparse.Namespace) -> int:
    """Train as configured by ``args``; 0 on success, 2 on a user error."""
    import torch

    from rmi_learn.world_models.training import train

    torch.set_num_threads(threads_of(args.threads))
    summary = train(
        model=args.model,
        model_args=_parse_model_args(args.model_arg),
        data=args.data,
        out=args.out,
        size_cm=args.size,
        state_groups=args.state_groups,
        shuffle_actions=args.shuffle_actions,
        epochs=args.epochs,
        patience=args.patience,
        tf_epochs=args.tf_epochs,
        batch_size=args.batch_size,
        steps_per_epoch=args.steps_per_epoch,
        water_weight=args.water_weight,
        huber_delta=args.huber_delta,
        loss_scale=args.loss_scale,
        lr=args.lr,
        val_windows=args.val_windows,
        seed=args.seed,
        deterministic=args.deterministic,
        device=args.device,
        resume=args.resume,
        debug=args.debug,
        progress=not args.no_progress,
        tensorboard=args.tensorboard,
        horizon=args.horizon,
        observation_mode=args.observation_mode,
        sensors=args.sensors,
        val_phases=args.val_phases,
    )
    print(json.dumps(summary, indent=2))
    return 0


def _sensor_model(text: str) -> SensorModel:
    """``--sensors``: a JSON object of :class:`~rmi_learn.sensing.SensorModel` fields."""
    try:
        fields = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not a JSON object ({exc.msg})") from exc
    try:
        return SensorModel.from_mapping(fields)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def _parse_model_args(items: list[str]) -> dict[str, Any]:
    """``["d_model=128", "dropout=0.2"]`` -> ``{"d_model": 128, "dropout": 0.2}``."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(f"--model-arg expects KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out
