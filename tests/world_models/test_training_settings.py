"""World-model training settings: the validation metric that selects the weights."""

from __future__ import annotations

from rmi_learn.world_models.training_settings import select_metric


def test_the_selection_step_lies_within_the_horizon() -> None:
    assert select_metric("val_water_mae_g@64", 64) == "val_water_mae_g@64"
    assert select_metric("val_water_mae_g@64", 32) == "val_water_mae_g@32"
    assert select_metric("val_water_mae_g@64", 20) == "val_water_mae_g@16"
    assert select_metric("val_water_mae_g_mean", 32) == "val_water_mae_g_mean"
