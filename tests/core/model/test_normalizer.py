import numpy as np
import pytest
import torch

from fignetctl.core.model.normalizer import Normalizer


def batches(seed=0):
    """Three batches of different sizes and ranks, float64, 3 features on different scales."""
    generator = np.random.default_rng(seed)
    scale, offset = np.array([1.0, 1e-3, 50.0]), np.array([0.0, 2.0, -7.0])
    shapes = [(5, 3), (2, 4, 3), (17, 3)]
    return [torch.from_numpy(generator.normal(size=shape) * scale + offset) for shape in shapes]


def test_running_statistics_equal_numpy_over_several_batches():
    normalizer = Normalizer(3)
    for batch in batches():
        normalizer(batch, accumulate=True)
    all_rows = np.concatenate([batch.reshape(-1, 3).numpy() for batch in batches()])
    np.testing.assert_allclose(normalizer.mean().numpy(), all_rows.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(normalizer.std().numpy(), all_rows.std(axis=0), rtol=1e-9)
    assert normalizer.count.item() == 30 and normalizer.num_accumulations.item() == 3


def test_inverse_undoes_forward():
    normalizer = Normalizer(3)
    for batch in batches():
        normalized = normalizer(batch, accumulate=True)
        torch.testing.assert_close(normalizer.inverse(normalized), batch, rtol=1e-12, atol=1e-12)
    float32_batch = batches(seed=1)[1].float()
    torch.testing.assert_close(normalizer.inverse(normalizer(float32_batch, accumulate=False)), float32_batch)


def test_normalized_batch_has_zero_mean_and_unit_std():
    normalizer = Normalizer(3)
    data = batches()[2]
    normalized = normalizer(data, accumulate=True)
    torch.testing.assert_close(
        normalized.mean(dim=0), torch.zeros(3, dtype=torch.float64), atol=1e-12, rtol=0
    )
    torch.testing.assert_close(normalized.std(dim=0, unbiased=False), torch.ones(3, dtype=torch.float64))


def test_constant_and_near_constant_features_give_finite_output():
    normalizer = Normalizer(2, std_epsilon=1e-8)
    constant = torch.full((50, 1), 0.7, dtype=torch.float32)
    near_constant = 3.0 + 1e-12 * torch.randn(50, 1, generator=torch.Generator().manual_seed(0))
    data = torch.cat([constant, near_constant.float()], dim=1)
    normalized = normalizer(data, accumulate=True)
    assert torch.isfinite(normalized).all()
    torch.testing.assert_close(normalized[:, 0], torch.zeros(50))
    assert (normalizer.std() >= 1e-8).all()


def test_mean_far_from_origin_keeps_an_accurate_std():
    generator = np.random.default_rng(2)
    data = 1e3 + generator.normal(size=(20000, 1))
    normalizer = Normalizer(1)
    for chunk in np.array_split(data, 10):
        normalizer(torch.from_numpy(chunk), accumulate=True)
    np.testing.assert_allclose(normalizer.std().numpy(), data.std(axis=0), rtol=1e-6)


def test_statistics_freeze_after_max_accumulations():
    normalizer = Normalizer(3, max_accumulations=2)
    first, second, third = batches()
    normalizer(first, accumulate=True)
    normalizer(second, accumulate=True)
    mean_after_two = normalizer.mean().clone()
    normalizer(third * 100, accumulate=True)
    torch.testing.assert_close(normalizer.mean(), mean_after_two)
    assert normalizer.num_accumulations.item() == 2


def test_statistics_travel_in_the_state_dict():
    trained = Normalizer(3)
    for batch in batches():
        trained(batch, accumulate=True)
    loaded = Normalizer(3)
    loaded.load_state_dict(trained.state_dict())
    probe = batches(seed=3)[0]
    torch.testing.assert_close(loaded(probe, accumulate=False), trained(probe, accumulate=False))
    assert trained.state_dict()["sum"].dtype == torch.float64


def test_normalizing_without_statistics_or_with_a_wrong_width_is_refused():
    with pytest.raises(RuntimeError, match="no statistics"):
        Normalizer(3)(torch.zeros(2, 3), accumulate=False)
    with pytest.raises(ValueError, match="width 4"):
        Normalizer(3)(torch.zeros(2, 4), accumulate=True)
