"""The fast training path: batches sliced from tensors in memory, a block of batches per
Lightning step, manual optimisation. It must train exactly as plain PyTorch would."""

from __future__ import annotations

import copy
from pathlib import Path

import lightning as L
import pytest
import torch
from torch.utils.data import BatchSampler, DataLoader, RandomSampler, TensorDataset

from hysteresis_lab.data.blocks import block_loader
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.fitting import build_model, fit
from narx import CONFIGS, TRAINER


def _plain_batches(n: int, batch_size: int, seed: int, epochs: int) -> list[list[torch.Tensor]]:
    rows = torch.arange(n)
    sampler = BatchSampler(
        RandomSampler(rows, generator=torch.Generator().manual_seed(seed)), batch_size, False
    )
    loader = DataLoader(TensorDataset(rows), sampler=sampler, batch_size=None)
    return [[batch[0] for batch in loader] for _ in range(epochs)]


@pytest.mark.parametrize("per_step", [1, 3, 50])
def test_blocks_hold_the_plain_loaders_batches_in_order(per_step):
    n, batch_size, seed = 1000, 64, 7  # a short last batch
    plain = _plain_batches(n, batch_size, seed, epochs=3)
    loader = block_loader((torch.arange(n),), batch_size, per_step, shuffle=True,
                          generator=torch.Generator().manual_seed(seed))
    assert len(loader) == -(-16 // per_step)
    for epoch in range(3):
        blocks = list(loader)
        assert len(blocks) == len(loader)
        batches = [b[0] for b in blocks] if per_step == 1 else [
            part[0] for block in blocks for part in block]
        if per_step > 1:
            assert all(len(block) <= per_step for block in blocks)
        assert [b.tolist() for b in batches] == [b.tolist() for b in plain[epoch]]
        every = torch.cat(batches)
        assert sorted(every.tolist()) == list(range(n))  # each row once per epoch
    assert plain[0][0].tolist() != plain[1][0].tolist()  # shuffled anew each epoch


def test_datamodule_blocks_cover_every_window_once(splits):
    dm = WindowDataModule(splits, batch_size=64, batches_per_step=4)
    dm.setup()
    x_all, target_all = dm._tensors["train"].tensors
    blocks = list(dm.train_dataloader())
    parts = [part for block in blocks for part in block]
    assert all(len(block) <= 4 for block in blocks) and len(parts) == -(-len(x_all) // 64)
    x = torch.cat([p[0] for p in parts])
    target = torch.cat([p[1] for p in parts])
    assert x.shape == x_all.shape
    order = torch.argsort(target[:, 0] * 1e3 + x[:, 0])
    expected = torch.argsort(target_all[:, 0] * 1e3 + x_all[:, 0])
    assert torch.equal(x[order], x_all[expected])
    val = [p for block in dm.val_dataloader() for p in block]
    assert torch.equal(torch.cat([p[0] for p in val]), dm._tensors["val"].tensors[0])


def _bare(model: L.LightningModule, dm: WindowDataModule, epochs: int,
          clip: float | None = None, losses: list[tuple[float, int]] | None = None
          ) -> L.LightningModule:
    """Plain PyTorch training with the plain loader's batches, Adam and the cosine schedule;
    ``losses`` gets each step's (loss, batch size)."""
    x, target = dm._tensors["train"].tensors
    lr = model.training_settings.lr
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, epochs, eta_min=lr * 0.01)
    for batches in _plain_batches(len(x), dm.batch_size, dm.seed, epochs):
        for rows in batches:
            loss = torch.nn.functional.mse_loss(model(x[rows]), target[rows])
            if losses is not None:
                losses.append((float(loss), len(rows)))
            optimizer.zero_grad()
            loss.backward()
            if clip is not None:
                torch.nn.utils.clip_grad_norm_(model.parameters(), clip)
            optimizer.step()
        schedule.step()
    return model


def _lightning(model: L.LightningModule, dm: WindowDataModule, epochs: int) -> None:
    trainer = L.Trainer(**TRAINER.with_changes(max_epochs=epochs).trainer_arguments(),
                        logger=False, enable_checkpointing=False)
    trainer.fit(model, datamodule=dm)


@pytest.mark.parametrize("name", ["ffnn", "lstm"])
def test_block_steps_train_as_plain_pytorch_does(splits, name):
    def datamodule(per_step: int) -> WindowDataModule:
        layout = "sequence" if name == "lstm" else "flat"
        return WindowDataModule(splits, layout=layout, scaling="standard", batch_size=64,
                                batches_per_step=per_step)

    torch.manual_seed(0)
    start = build_model(CONFIGS[name], datamodule(1))
    trained = {}
    for per_step in (1, 8):
        model = copy.deepcopy(start)
        _lightning(model, datamodule(per_step), epochs=2)
        trained[per_step] = model.state_dict()
    dm = datamodule(1)
    dm.setup()
    bare = _bare(copy.deepcopy(start), dm, epochs=2).state_dict()
    moved = 0.0
    for key, value in bare.items():
        assert torch.allclose(trained[8][key], trained[1][key], rtol=0, atol=1e-7), key
        assert torch.allclose(trained[8][key], value, rtol=1e-5, atol=1e-6), key
        moved = max(moved, float((value - start.state_dict()[key]).abs().max()))
    assert moved > 1e-3  # it trained


def test_trainer_gradient_clipping_is_applied_by_the_module(splits, tmp_path: Path):
    dm = WindowDataModule(splits, scaling="standard", batch_size=64)
    dm.setup()
    torch.manual_seed(0)
    start = build_model(CONFIGS["ffnn"], dm)
    clipped = copy.deepcopy(start)
    # one epoch: the best checkpoint fit keeps is the last one
    fit(clipped, dm, TRAINER.with_changes(max_epochs=1, gradient_clip_val=1e-3), tmp_path)
    losses: list[tuple[float, int]] = []
    bare_clipped = _bare(copy.deepcopy(start), dm, epochs=1, clip=1e-3, losses=losses).state_dict()
    mean = sum(loss * size for loss, size in losses) / sum(size for _, size in losses)
    logged = float(clipped.trainer.callback_metrics["train_loss"])
    assert logged == pytest.approx(mean, rel=1e-5)  # the epoch's loss, not the clip value
    bare_free = _bare(copy.deepcopy(start), dm, epochs=1).state_dict()
    for key, value in clipped.state_dict().items():
        assert torch.allclose(value, bare_clipped[key], rtol=1e-5, atol=1e-6), key
    assert any(not torch.allclose(v, bare_free[k], atol=1e-4) for k, v in bare_clipped.items())


def test_plateau_schedule_steps_on_the_validation_loss(splits):
    dm = WindowDataModule(splits, scaling="standard", batch_size=64)
    model = build_model({**CONFIGS["ffnn"], "lr_schedule": "plateau"}, dm)
    _lightning(model, dm, epochs=2)
    scheduler = model.lr_schedulers()
    assert isinstance(scheduler, torch.optim.lr_scheduler.ReduceLROnPlateau)
    assert scheduler.last_epoch == 2
    assert float(scheduler.best) == pytest.approx(float(model.trainer.callback_metrics["val_loss"]),
                                                  rel=1e-6) or scheduler.num_bad_epochs > 0


class _BackwardCounter(L.Callback):
    def __init__(self) -> None:
        self.calls = 0

    def on_before_backward(self, trainer, pl_module, loss) -> None:
        self.calls += 1


def test_steps_are_counted_and_step_hooks_still_run_where_overridden(splits):
    """The direct step (no Lightning wrapper around backward and the optimiser step) still
    counts every step, and a callback with a backward hook gets the full path: both train
    the same weights."""
    dm = WindowDataModule(splits, scaling="standard", batch_size=64, batches_per_step=8)
    dm.setup()
    batches = -(-len(dm._tensors["train"]) // 64)
    torch.manual_seed(0)
    start = build_model(CONFIGS["ffnn"], dm)
    direct, hooked = copy.deepcopy(start), copy.deepcopy(start)
    _lightning(direct, dm, epochs=2)
    assert direct._direct_steps(direct.optimizers())
    assert direct.trainer.global_step == 2 * batches
    counter = _BackwardCounter()
    trainer = L.Trainer(**TRAINER.with_changes(max_epochs=2).trainer_arguments(),
                        logger=False, enable_checkpointing=False, callbacks=[counter])
    trainer.fit(hooked, datamodule=dm)
    assert not hooked._direct_steps(hooked.optimizers())
    assert counter.calls == 2 * batches and trainer.global_step == 2 * batches
    for key, value in direct.state_dict().items():
        assert torch.allclose(value, hooked.state_dict()[key], rtol=0, atol=1e-7), key
