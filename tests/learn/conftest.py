"""Shared fixtures of the learned-model tests: thread pinning, tiny test images, parameter perturbation,
the Haar/identity state of a freshly built flow."""

from __future__ import annotations

import pytest
import torch

from nanoct.learn.invertible import ConditionalNICECoupling, haar_matrix


@pytest.fixture
def one_thread():
    """Tiny tensors: one thread is much faster, and immune to a busy second core.

    Not autouse: the modules of tiny invertible networks opt in with
    ``pytestmark = pytest.mark.usefixtures("one_thread")``.
    """
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _images(b: int, h: int, w: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(b, 1, h, w, generator=g)
    x = torch.nn.functional.avg_pool2d(x, 3, stride=1, padding=1)  # some spatial structure
    x_tilde = x + 0.1 * torch.randn(b, 1, h, w, generator=g)
    return x_tilde, x


def _perturb(model: torch.nn.Module, std: float = 0.05, seed: int = 0) -> None:
    """Move every parameter off its initial value (zero last layers, Haar kernels)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            if p.requires_grad and p.is_floating_point():
                p.add_(std * torch.randn(p.shape, generator=g, dtype=p.dtype))


@pytest.fixture
def images():
    """``images(b, h, w, seed) -> (x_tilde, x)``: smooth random images and noisy copies of them."""
    return _images


@pytest.fixture
def perturb():
    """``perturb(model, std=0.05, seed=0)``: add seeded Gaussian noise to every float parameter."""
    return _perturb


def _check_haar_init(model: torch.nn.Module, resampling: tuple[type, ...], n_resampling: int, n_couplings: int) -> None:
    """At initialisation every resampling kernel is the orthogonal Haar matrix and every coupling is the identity."""
    res = [mod for mod in model.modules() if isinstance(mod, resampling)]
    assert len(res) == n_resampling
    for d in res:
        w = d.kernels.weight.detach()
        torch.testing.assert_close(w @ w.transpose(1, 2), torch.eye(4).expand_as(w), atol=1e-6, rtol=0)
        torch.testing.assert_close(w, haar_matrix().expand_as(w))
    couplings = [mod for mod in model.modules() if isinstance(mod, ConditionalNICECoupling)]
    assert len(couplings) == n_couplings
    for c in couplings:
        for sub in (c.F, c.G):
            assert torch.all(sub[-1].weight == 0) and torch.all(sub[-1].bias == 0)


@pytest.fixture
def check_haar_init():
    """``check_haar_init(model, resampling_types, n_resampling, n_couplings)``: Haar kernels, zero last layers."""
    return _check_haar_init
