"""Per-photo appearance (training/appearance.py): gains absorb each photo's exposure, the
field keeps the scene's colour, and the trainer learns them when asked (off by default)."""

from __future__ import annotations

import torch

from neoedit.training.appearance import PhotoAppearance


def test_gains_absorb_each_photos_exposure_and_the_colour_stays_the_scenes():
    true = torch.tensor([0.6, 0.4, 0.2])
    exposure = torch.tensor([1.0, 1.0, 0.7, 1.0, 1.3, 1.0])  # photo 2 dark, photo 4 bright
    colour = torch.zeros(3, requires_grad=True)  # the "field": one colour
    field_opt = torch.optim.Adam([colour], lr=1e-2)
    appearance = PhotoAppearance(len(exposure), 1e-2, torch.device("cpu"))
    gen = torch.Generator().manual_seed(0)
    for _ in range(3000):
        photo = torch.randint(0, len(exposure), (256,), generator=gen)
        target = true * exposure[photo, None]
        rgb = appearance.apply(colour.expand(256, 3), photo)
        loss = ((rgb - target) ** 2).mean() + appearance.penalty()
        appearance.zero_grad()
        field_opt.zero_grad()
        loss.backward()
        field_opt.step()
        appearance.step()
    # the neutral render is the scene under the typical exposure, not pulled by the outliers
    torch.testing.assert_close(colour.detach(), true, atol=0.02, rtol=0)
    shown = appearance.apply(colour.detach().expand(6, 3), torch.arange(6))
    torch.testing.assert_close(shown, true * exposure[:, None], atol=0.02, rtol=0)


def test_the_trainer_learns_appearance_when_asked(tmp_path):
    from neoedit.data import load_scene_data
    from neoedit.training.trainer import TrainConfig
    from tests.conftest import tiny_trainer
    from tests.test_background import _environment_dataset

    _environment_dataset(tmp_path / "photos", n=6)
    data = load_scene_data(tmp_path / "photos")
    assert data.alpha is None
    trainer = tiny_trainer(
        tmp_path / "photos",
        0.05,
        TrainConfig(max_steps=3, rays_per_batch=256, photo_appearance=True),
    )
    assert trainer.appearance is not None and trainer.appearance.params.shape == (
        len(data.split["train"]),
        6,
    )
    assert float(trainer.appearance.params.detach().abs().sum()) > 0  # it trained
    off = tiny_trainer(tmp_path / "photos", 0.05, TrainConfig(max_steps=1, rays_per_batch=256))
    assert off.appearance is None
