"""CiUNet-specific checks: the paper's structure, the reversed UNet wiring, the Haar identity at initialisation.

The tests shared with the CiNNs (invertibility, exact log-det, training, sampling, checkpoints)
are parametrised over all four architectures in test_flows.py.
"""

from __future__ import annotations

import pytest
import torch
from test_flows import CIUNET_TINY as TINY

from nanoct.learn.ciunet import CiUNet, CiUNetRes
from nanoct.learn.invertible import OrthogonalDownsampling, OrthogonalUpsampling
from nanoct.learn.unet import UNet

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.parametrize("cls", [CiUNet, CiUNetRes])
def test_conditioner_is_a_unet(cls):
    assert isinstance(cls(**TINY).cond_net, UNet)


def test_paper_structure():
    m = CiUNet()  # paper defaults: 5 scales, UNet (32, 32, 64, 64, 128) conditioner
    assert m.multiple == 16 and m.latent_dim(255, 255) == 256 * 256
    dims = {node.name: node.output_dims[0] for node in m.flow.node_list if node.output_dims}
    assert dims["down_1"][0] == 4 and dims["down_4"][0] == 32  # coarsest level: 32 channels
    assert dims["concat_1"][0] == 4 and dims["up_0"][0] == 1
    # reversed connection: encoder couplings get UNet decoder features and vice versa
    conds = {node.name: node.output_dims[0] for node in m.flow.condition_nodes}
    assert conds["cond_dec_4"] == (128, 1, 1) and conds["cond_enc_1"] == (32, 8, 8)
    coupling = {
        node.name: [c.name for c in node.conditions] for node in m.flow.node_list if node.name.startswith("coupling_")
    }
    assert coupling["coupling_pre_0"] == ["cond_dec_1"] and coupling["coupling_enc4_0"] == ["cond_dec_4"]
    assert coupling["coupling_dec1_1"] == ["cond_enc_1"]


def test_conditions_come_from_the_unet_in_reversed_order():
    m = CiUNet(**TINY).eval()
    xt = torch.rand(2, 1, 8, 8)
    conds = m.condition(xt)
    _, enc, dec = m.cond_net.forward_features(xt)
    assert [tuple(c.shape) for c in conds] == [(2, 4, 4, 4), (2, 8, 2, 2), (2, 4, 4, 4)]
    torch.testing.assert_close(conds[0], dec[1])  # encoder level 1 <- UNet decoder level 1
    torch.testing.assert_close(conds[1], enc[2])  # coarsest <- UNet bottleneck
    torch.testing.assert_close(conds[2], enc[1])  # decoder level 1 <- UNet encoder level 1


def test_resampling_orthogonal_haar_and_couplings_identity_at_init(images, check_haar_init):
    check_haar_init(
        CiUNet(**TINY), (OrthogonalDownsampling, OrthogonalUpsampling), n_resampling=2 + 2 + 2, n_couplings=1 + 2 + 1
    )  # resampling: pre-block, encoder, decoder
    # so, without ActNorm after the couplings, the flow is (input ActNorm +) Haar down/up = identity
    m = CiUNet(**{**TINY, "actnorm": False})
    x_tilde, x = images(2, 8, 8, seed=3)
    z1, lj = m(x, x_tilde)
    z2, _ = m(x, torch.randn_like(x_tilde))
    torch.testing.assert_close(z1, z2)
    an = m.flow.get_module_by_name("actnorm_in")
    expected = (x * an.scale.exp() + an.bias).reshape(2, -1)
    torch.testing.assert_close(z1, expected, atol=1e-5, rtol=0)
    # strings from a caller are read as the words they are (bool("False") would be True)
    words = CiUNet(**{**TINY, "actnorm": "false", "cond_norm": "FALSE"})
    assert words.hparams["actnorm"] is False and words.hparams["cond_norm"] is False
    assert not any(isinstance(mod, torch.nn.BatchNorm2d) for mod in words.cond_net.modules())
    for key in ("actnorm", "cond_norm"):
        with pytest.raises(ValueError, match=f"{key}='off' is not a boolean"):
            CiUNet(**{**TINY, key: "off"})
