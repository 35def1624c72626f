"""CiNN and CiNNRes on tiny inputs: invertibility, exact log-det, training, sampling, checkpoints."""

from __future__ import annotations

import io

import pytest
import torch
from torch.autograd.functional import jacobian

from nanoct.learn.cinn import CiNN, CiNNRes
from nanoct.learn.invertible import (
    CheckpointMismatchError,
    ConditionalNICECoupling,
    OrthogonalDownsampling,
    haar_matrix,
)

TINY = dict(n_scales=3, blocks_per_scale=2, fc_dim=8, fc_blocks=2, cond_channels=4, cond_width=4, fc_cond_dim=8,
            hidden_ratio=1.0)
CLASSES = [CiNN, CiNNRes]


@pytest.fixture(autouse=True)
def _one_thread():
    """Tiny tensors: one thread is much faster, and immune to a busy second core."""
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


@pytest.mark.parametrize("cls", CLASSES)
def test_names_and_hparams(cls):
    m = cls(**TINY)
    assert m.name == ("cinn-res" if cls is CiNNRes else "cinn")
    assert m.residual is (cls is CiNNRes)
    assert m.hparams["n_scales"] == 3 and m.hparams["cond_channels"] == [4, 4]
    assert set(m.hparams) >= set(TINY) | {"actnorm", "target_noise", "orthogonal_map", "seed"}
    assert m.hparams["target_noise"] == 0.005
    cls(**m.hparams)  # hparams rebuild the model
    d = CiNN().hparams  # paper defaults
    assert d["n_scales"] == 6 and d["fc_dim"] == 128 and CiNN().multiple == 64


@pytest.mark.parametrize("cls", CLASSES)
@pytest.mark.parametrize("size", [(8, 8), (13, 10)])
def test_inverse_of_forward_is_identity(cls, size):
    torch.manual_seed(0)
    m = cls(**TINY)
    x_tilde, x = _images(3, *size, seed=1)
    m(x, x_tilde)  # ActNorm data initialisation
    _perturb(m)
    v = m._target(x_tilde, x)
    z, log_jac = m(v, x_tilde)
    assert z.shape == (3, m.latent_dim(*size)) and log_jac.shape == (3,)
    torch.testing.assert_close(m.inverse(z, x_tilde), v, atol=1e-4, rtol=0)


@pytest.mark.parametrize("cls", CLASSES)
def test_logdet_matches_brute_force_jacobian(cls):
    torch.manual_seed(0)
    m = cls(**TINY).double().eval()
    x_tilde, x = (t.double() for t in _images(1, 8, 8, seed=2))
    m(x, x_tilde)  # ActNorm data initialisation
    _perturb(m, std=0.1)
    _, log_jac = m(x, x_tilde)
    jmat = jacobian(lambda v: m(v.view(1, 1, 8, 8), x_tilde)[0].reshape(-1), x.reshape(-1))
    assert jmat.shape == (64, 64)
    sign, logabs = torch.linalg.slogdet(jmat)
    assert sign != 0
    assert abs(logabs.item() - log_jac.item()) < 1e-6 * max(1.0, abs(logabs.item()))


def test_resampling_orthogonal_haar_and_couplings_identity_at_init():
    m = CiNN(**TINY)
    downs = [mod for mod in m.modules() if isinstance(mod, OrthogonalDownsampling)]
    assert len(downs) == 3
    for d in downs:
        w = d.kernels.weight.detach()
        torch.testing.assert_close(w @ w.transpose(1, 2), torch.eye(4).expand_as(w), atol=1e-6, rtol=0)
        torch.testing.assert_close(w, haar_matrix().expand_as(w))
    couplings = [mod for mod in m.modules() if isinstance(mod, ConditionalNICECoupling)]
    assert len(couplings) == 2 * 2 + 2
    for c in couplings:
        for sub in (c.F, c.G):
            assert torch.all(sub[-1].weight == 0) and torch.all(sub[-1].bias == 0)
    # so, without ActNorm, the whole flow is the (orthogonal) Haar pyramid: independent of the condition
    m = CiNN(**{**TINY, "actnorm": False})
    x_tilde, x = _images(2, 8, 8, seed=3)
    z1, lj = m(x, x_tilde)
    z2, _ = m(x, torch.randn_like(x_tilde))
    torch.testing.assert_close(z1, z2)
    torch.testing.assert_close(z1.norm(dim=1), x.reshape(2, -1).norm(dim=1))
    assert torch.all(lj == 0)


@pytest.mark.parametrize("cls", CLASSES)
def test_nll_decreases_in_short_training(cls):
    torch.manual_seed(0)
    m = cls(**TINY)
    x_tilde, x = _images(8, 8, 8, seed=4)
    opt = torch.optim.Adam(m.parameters(), lr=2e-3)
    losses = []
    for _ in range(30):
        loss, metrics = m.loss(x_tilde, x)
        assert set(metrics) >= {"nll_bpd"}
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(m.parameters(), 1.0)
        opt.step()
        losses.append(loss.item())
    assert sum(losses[-3:]) / 3 < sum(losses[:3]) / 3 - 0.1, losses


@pytest.mark.parametrize("cls", CLASSES)
def test_different_conditions_give_different_samples(cls):
    torch.manual_seed(0)
    m = cls(**TINY).eval()
    x_tilde, x = _images(2, 8, 8, seed=5)
    m(x, x_tilde)
    _perturb(m, std=0.2)
    z = torch.randn(1, 64).expand(2, 64)
    v = m.inverse(z, x_tilde)  # the flow's own output (x, or dx for the residual variant)
    assert (v[0] - v[1]).abs().max() > 1e-3
    v_same = m.inverse(z, x_tilde[:1].expand(2, -1, -1, -1))
    torch.testing.assert_close(v_same[0], v_same[1])


@pytest.mark.parametrize("cls", CLASSES)
def test_reconstruct_follows_the_paper_formulas(cls):
    torch.manual_seed(0)
    m = cls(**TINY).eval()
    x_tilde, x = _images(1, 13, 10, seed=6)
    m(x, x_tilde)
    _perturb(m)
    n = 12
    mean, std = m.reconstruct(x_tilde, n_samples=n, chunk=n, generator=torch.Generator().manual_seed(7))
    assert mean.shape == std.shape == x_tilde.shape and torch.all(std >= 0) and std.max() > 0
    z = torch.randn(n, m.latent_dim(13, 10), generator=torch.Generator().manual_seed(7))
    v = m.inverse(z, x_tilde.expand(n, -1, -1, -1))  # samples of x (or of dx)
    expected_mean = x_tilde[0] - v.mean(0) if m.residual else v.mean(0)
    torch.testing.assert_close(mean[0], expected_mean, atol=1e-5, rtol=0)
    torch.testing.assert_close(std[0], v.std(0, unbiased=False), atol=1e-5, rtol=0)
    # chunking only changes how the samples are batched
    s = m.sample(x_tilde.expand(2, -1, -1, -1), n_samples=5, chunk=3)
    assert s.shape == (2, 5, 1, 13, 10)
    mean2, std2 = m.reconstruct(x_tilde.expand(2, -1, -1, -1), n_samples=5, chunk=3,
                                generator=torch.Generator().manual_seed(8))
    s2 = m.sample(x_tilde.expand(2, -1, -1, -1), n_samples=5, chunk=3, generator=torch.Generator().manual_seed(8))
    torch.testing.assert_close(mean2, s2.mean(1), atol=1e-5, rtol=0)
    torch.testing.assert_close(std2, s2.std(1, unbiased=False), atol=1e-5, rtol=0)


@pytest.mark.parametrize("cls", CLASSES)
def test_bad_input_raises(cls):
    m = cls(**TINY).eval()
    x_tilde, x = _images(2, 8, 8, seed=9)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="n_samples"):
            m.reconstruct(x_tilde, n_samples=bad)
    with pytest.raises(ValueError, match="chunk"):
        m.reconstruct(x_tilde, n_samples=2, chunk=0)
    with pytest.raises(ValueError, match="condition"):
        m.reconstruct(x_tilde[:, 0])
    with pytest.raises(ValueError, match="condition"):
        m.reconstruct(x_tilde.expand(2, 2, 8, 8))
    with pytest.raises(ValueError, match="shape"):
        m.loss(x_tilde[:, :, :7], x)
    with pytest.raises(ValueError, match="shape"):
        m.inverse(torch.randn(2, 63), x_tilde)
    with pytest.raises(ValueError, match="shape"):
        m(x, x_tilde[:1])
    with pytest.raises(ValueError):
        cls(**{**TINY, "cond_channels": [4, 4, 4]})
    with pytest.raises(ValueError):
        cls(**{**TINY, "fc_dim": 64})  # more than the coarsest signal of an 8x8 image


@pytest.mark.parametrize("cls", CLASSES)
def test_state_dict_round_trip_and_mismatch(cls):
    torch.manual_seed(0)
    m = cls(**TINY).eval()
    x_tilde, x = _images(2, 13, 10, seed=10)
    m(x, x_tilde)
    _perturb(m)
    buf = io.BytesIO()
    torch.save({"hparams": m.hparams, "state": m.state_dict()}, buf)
    buf.seek(0)
    ckpt = torch.load(buf, weights_only=True)
    m2 = cls(**ckpt["hparams"]).eval()
    m2.load_state_dict(ckpt["state"])
    z, lj = m(x, x_tilde)
    z2, lj2 = m2(x, x_tilde)
    assert torch.equal(z, z2) and torch.equal(lj, lj2)
    r = m.reconstruct(x_tilde, n_samples=4, generator=torch.Generator().manual_seed(1))
    r2 = m2.reconstruct(x_tilde, n_samples=4, seed=1)
    assert torch.equal(r[0], r2[0]) and torch.equal(r[1], r2[1])
    with pytest.raises(CheckpointMismatchError, match="does not match"):
        cls(**{**TINY, "blocks_per_scale": 3}).load_state_dict(ckpt["state"])
    with pytest.raises(ValueError):
        cls(**{**TINY, "cond_channels": 6}).load_state_dict(ckpt["state"])
    with pytest.raises(RuntimeError):  # what torch's own handlers expect
        cls(**{**TINY, "n_scales": 2, "cond_channels": 4}).load_state_dict(ckpt["state"])
