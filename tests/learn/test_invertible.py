"""Building blocks of the conditional invertible networks (nanoct.learn.invertible)."""

from __future__ import annotations

import math

import FrEIA.framework as Ff
import pytest
import torch
from torch.autograd.functional import jacobian

from nanoct.learn.invertible import (
    ActNorm,
    ConditionalNICECoupling,
    ConditionalScale,
    OrthogonalDownsampling,
    OrthogonalUpsampling,
    RunningMoments,
    crop,
    gaussian_nll_bpd,
    haar_matrix,
    pad_to_multiple,
    preserve_numpy_rng,
    scale_form,
)

pytestmark = pytest.mark.usefixtures("one_thread")


def test_haar_matrix_is_orthogonal():
    h = haar_matrix(torch.float64)
    torch.testing.assert_close(h @ h.T, torch.eye(4, dtype=torch.float64))


@pytest.mark.parametrize("cls", [OrthogonalDownsampling, OrthogonalUpsampling])
def test_resampling_is_orthogonal_and_haar_at_init(cls):
    dims = (3, 8, 8) if cls is OrthogonalDownsampling else (12, 4, 4)
    m = cls([dims]).double()
    w = m.kernels.weight
    assert w.shape == (3, 4, 4)
    eye = torch.eye(4, dtype=torch.float64).expand(3, 4, 4)
    torch.testing.assert_close(w @ w.transpose(1, 2), eye)
    torch.testing.assert_close(w, haar_matrix(torch.float64).expand(3, 4, 4))


def test_downsampling_computes_haar_subbands_in_subband_order():
    m = OrthogonalDownsampling([(2, 4, 6)])
    x = torch.randn(3, 2, 4, 6)
    (y,), jac = m([x])
    assert y.shape == (3, 8, 2, 3)
    a, b, c, d = x[..., ::2, ::2], x[..., ::2, 1::2], x[..., 1::2, ::2], x[..., 1::2, 1::2]
    torch.testing.assert_close(y[:, 0:2], (a + b + c + d) / 2)  # subband 0 of channels 0, 1
    torch.testing.assert_close(y[:, 2:4], (a - b + c - d) / 2)
    torch.testing.assert_close(y[:, 6:8], (a - b - c + d) / 2)
    assert torch.all(jac == 0)


def test_resampling_stays_orthogonal_after_training_and_inverts():
    torch.manual_seed(0)
    down = OrthogonalDownsampling([(2, 8, 8)])
    opt = torch.optim.Adam(down.parameters(), lr=0.1)
    x = torch.randn(4, 2, 8, 8)
    for _ in range(5):
        (y,), _ = down([x])
        loss = (y[:, :2] ** 2).sum()  # push energy out of the low-pass band
        opt.zero_grad()
        loss.backward()
        opt.step()
    w = down.kernels.weight.detach()
    assert not torch.allclose(w, haar_matrix().expand(2, 4, 4), atol=1e-3)  # it learned
    torch.testing.assert_close(w @ w.transpose(1, 2), torch.eye(4).expand(2, 4, 4), atol=1e-5, rtol=0)
    with torch.no_grad():
        (y,), _ = down([x])
        (xr,), _ = down([y], rev=True)
    torch.testing.assert_close(xr, x, atol=1e-5, rtol=0)


def test_resampling_logdet_is_zero_by_brute_force():
    torch.manual_seed(1)
    down = OrthogonalDownsampling([(1, 4, 4)]).double()
    with torch.no_grad():
        down.kernels.weight = torch.linalg.qr(torch.randn(1, 4, 4, dtype=torch.float64))[0]
    x = torch.randn(16, dtype=torch.float64)
    jmat = jacobian(lambda v: down([v.view(1, 1, 4, 4)])[0][0].reshape(-1), x)
    assert abs(torch.linalg.slogdet(jmat)[1].item()) < 1e-10
    up, down0 = OrthogonalUpsampling([(4, 2, 2)]), OrthogonalDownsampling([(1, 4, 4)])
    (x2,), _ = up(down0([x.view(1, 1, 4, 4).float()])[0])
    torch.testing.assert_close(x2, x.view(1, 1, 4, 4).float())  # both Haar at init: up = down^-1


@pytest.mark.parametrize("shape, cond", [((4, 6, 6), (3, 6, 6)), ((10,), (5,))])
def test_conditional_coupling_is_identity_at_init_and_invertible(shape, cond):
    torch.manual_seed(2)
    block = ConditionalNICECoupling([shape], [cond], kernel_size=3)
    x, c = torch.randn(2, *shape), torch.randn(2, *cond)
    (y,), jac = block([x], [c])
    torch.testing.assert_close(y, x)
    assert torch.all(jac == 0)
    for sub in (block.F, block.G):
        assert torch.all(sub[-1].weight == 0) and torch.all(sub[-1].bias == 0)
        torch.nn.init.normal_(sub[-1].weight, std=0.1)
    (y,), _ = block([x], [c])
    assert not torch.allclose(y, x)
    (y2,), _ = block([x], [c + 1])
    assert not torch.allclose(y, y2)  # the condition matters
    (xr,), _ = block([y], [c], rev=True)
    torch.testing.assert_close(xr, x, atol=1e-5, rtol=0)


def test_actnorm_logdet_at_any_size_and_safe_init():
    an = ActNorm([(2, 4, 4)])
    x = torch.randn(8, 2, 6, 10) * torch.tensor([3.0, 0.5]).view(1, 2, 1, 1)
    (y,), jac = an([x])  # data-dependent initialisation
    torch.testing.assert_close(y.mean(dim=(0, 2, 3)), torch.zeros(2), atol=1e-5, rtol=0)
    torch.testing.assert_close(y.std(dim=(0, 2, 3)), torch.ones(2), atol=1e-4, rtol=0)
    torch.testing.assert_close(jac, (an.scale.sum() * 60).expand(8))  # 6x10, not the 4x4 it was built for
    (xr,), jrev = an([y], rev=True)
    torch.testing.assert_close(xr, x, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(jrev, -jac)

    const = ActNorm([(1, 3, 3)])
    (y,), jac = const([torch.ones(2, 1, 3, 3)])
    assert torch.isfinite(y).all() and torch.isfinite(jac).all()

    fresh = ActNorm([(1, 3, 3)])
    (y,), _ = fresh([torch.randn(2, 1, 3, 3) * 7], rev=True)  # first call in reverse: no init
    assert fresh.scale.abs().sum() == 0 and not fresh.init_on_next_batch


def test_graph_of_blocks_logdet_matches_brute_force():
    torch.manual_seed(3)
    with preserve_numpy_rng():
        cond = Ff.ConditionNode(2, 2, 2)
        nodes = [Ff.InputNode(1, 4, 4)]
        nodes.append(Ff.Node(nodes[-1], ActNorm, {}))
        nodes.append(Ff.Node(nodes[-1], OrthogonalDownsampling, {}))
        nodes.append(Ff.Node(nodes[-1], ConditionalNICECoupling, {}, conditions=cond))
        nodes.append(Ff.Node(nodes[-1], ActNorm, {}))
        nodes.append(Ff.Node(nodes[-1], OrthogonalUpsampling, {}))
        nodes.append(Ff.OutputNode(nodes[-1]))
        net = Ff.GraphINN(nodes + [cond]).double()
    for p in net.parameters():
        if p.requires_grad:
            p.data.add_(0.1 * torch.randn_like(p))
    c = torch.randn(1, 2, 2, 2, dtype=torch.float64)
    x = torch.randn(1, 1, 4, 4, dtype=torch.float64)
    _, log_jac = net(x, c=c)
    jmat = jacobian(lambda v: net(v.view(1, 1, 4, 4), c=c)[0].reshape(-1), x.reshape(-1))
    assert abs(torch.linalg.slogdet(jmat)[1].item() - log_jac.item()) < 1e-8
    assert abs(log_jac.item()) > 1e-3  # non-trivial


def test_pad_and_crop_round_trip():
    x = torch.randn(2, 1, 13, 7)
    p = pad_to_multiple(x, 8, value=0.0)
    assert p.shape == (2, 1, 16, 8)
    assert torch.all(p[..., 13:, :] == 0) and torch.all(p[..., :, 7:] == 0)
    torch.testing.assert_close(crop(p, (13, 7)), x)
    r = pad_to_multiple(x, 8, mode="reflect")
    torch.testing.assert_close(r[..., 13, :7], x[..., 11, :])
    assert pad_to_multiple(torch.randn(1, 1, 2, 2), 8, mode="reflect").shape == (1, 1, 8, 8)  # falls back
    assert pad_to_multiple(x[..., :8, :], 8).shape == (2, 1, 8, 8)


def test_gaussian_nll_bpd_matches_torch_distributions():
    z = torch.randn(3, 20)
    log_jac = torch.randn(3)
    expected = -(torch.distributions.Normal(0.0, 1.0).log_prob(z).sum(1) + log_jac) / (20 * math.log(2))
    torch.testing.assert_close(gaussian_nll_bpd(z, log_jac), expected)


def test_running_moments_match_direct_computation_for_any_chunking():
    torch.manual_seed(4)
    values = 5.0 + 0.01 * torch.randn(3, 50, 4)  # large mean, small spread: no cancellation
    index = torch.arange(3).repeat_interleave(50)
    flat = values.reshape(150, 4)
    for chunk in (1, 7, 150):
        rm = RunningMoments(3, (4,))
        for r0 in range(0, 150, chunk):
            rm.update(flat[r0 : r0 + chunk], index[r0 : r0 + chunk])
        mean, std = rm.result()
        torch.testing.assert_close(mean, values.double().mean(1))
        torch.testing.assert_close(std, values.double().std(1, unbiased=False))


@pytest.mark.parametrize("form", ["location", "shift"])
def test_conditional_scale_inverts_and_logdet_matches_brute_force(form):
    torch.manual_seed(5)
    layer = ConditionalScale([(2, 3, 3)], [(4, 3, 3)], form=form)
    c = torch.randn(2, 4, 3, 3, dtype=torch.float64)
    x = torch.randn(2, 2, 3, 3, dtype=torch.float64)
    (y,), log_det = layer([x], c=[c])
    (back,), log_det_rev = layer([y], c=[c], rev=True)
    torch.testing.assert_close(back, x, rtol=0, atol=1e-12)
    torch.testing.assert_close(log_det_rev, -log_det)
    for i in range(2):
        ci = c[i : i + 1]
        jmat = jacobian(lambda v, ci=ci: layer([v.view(1, 2, 3, 3)], c=[ci])[0][0].reshape(-1), x[i].reshape(-1))
        assert abs(torch.linalg.slogdet(jmat)[1].item() - log_det[i].item()) < 1e-10


def test_conditional_scale_location_form_has_the_head_output_as_location_and_spread():
    # inverse of a standard normal y: x = y * exp(-s) + mu, so mean mu and std exp(-s) per pixel
    layer = ConditionalScale([(1, 2, 2)], [(2, 2, 2)], clamp=3.0, form="location")
    raw_s = torch.tensor([0.0, 0.5, -0.5, 1.0]).view(1, 1, 2, 2)
    mu = torch.tensor([0.3, -2.0, 5.0, 0.0]).view(1, 1, 2, 2)
    c = torch.cat([raw_s, mu], dim=1)
    y = torch.randn(20000, 1, 2, 2, generator=torch.Generator().manual_seed(0))
    (x,), _ = layer([y], c=[c.expand(20000, -1, -1, -1)], rev=True)
    s = 3.0 * 0.636 * torch.atan(raw_s)
    torch.testing.assert_close(x.mean(0), mu[0], atol=0.05, rtol=0)
    torch.testing.assert_close(x.std(0), torch.exp(-s)[0], atol=0, rtol=0.03)
    # the shift form puts its location at -t * exp(-s) instead
    (x_shift,), _ = ConditionalScale([(1, 2, 2)], [(2, 2, 2)], form="shift")(
        [y], c=[c.expand(20000, -1, -1, -1)], rev=True
    )
    torch.testing.assert_close(x_shift.mean(0), (-mu * torch.exp(-s))[0], atol=0.05, rtol=0)


def test_scale_form_reads_the_networks_argument():
    assert scale_form(False) is None and scale_form("none") is None
    assert scale_form(True) == "shift" and scale_form("shift") == "shift"
    assert scale_form("location") == "location"
    for bad in ("loc", 1, None):
        with pytest.raises(ValueError, match="conditional_scale"):
            scale_form(bad)
    with pytest.raises(ValueError, match="form"):
        ConditionalScale([(1, 2, 2)], [(2, 2, 2)], form="scale")
