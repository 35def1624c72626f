"""CiNN-specific checks: paper defaults, the Haar pyramid at initialisation.

The tests shared with CiNNRes and the CiUNets (invertibility, exact log-det, training, sampling, checkpoints)
are parametrised over all four architectures in test_flows.py.
"""

from __future__ import annotations

import pytest
import torch
from test_flows import CINN_TINY as TINY

from nanoct.learn.cinn import CiNN
from nanoct.learn.invertible import OrthogonalDownsampling

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.slow
def test_paper_defaults():
    d = CiNN().hparams  # paper defaults
    assert d["n_scales"] == 6 and d["fc_dim"] == 128 and CiNN().multiple == 64


def test_resampling_orthogonal_haar_and_couplings_identity_at_init(images, check_haar_init):
    check_haar_init(CiNN(**TINY), (OrthogonalDownsampling,), n_resampling=3, n_couplings=2 * 2 + 2)
    # so, without ActNorm, the whole flow is the (orthogonal) Haar pyramid: independent of the condition
    m = CiNN(**{**TINY, "actnorm": False})
    x_tilde, x = images(2, 8, 8, seed=3)
    z1, lj = m(x, x_tilde)
    z2, _ = m(x, torch.randn_like(x_tilde))
    torch.testing.assert_close(z1, z2)
    torch.testing.assert_close(z1.norm(dim=1), x.reshape(2, -1).norm(dim=1))
    assert torch.all(lj == 0)
    # a string from a caller is read as the word it is (bool("False") would be True), anything else refused
    assert CiNN(**{**TINY, "actnorm": "False"}).hparams["actnorm"] is False
    with pytest.raises(ValueError, match="actnorm='no' is not a boolean"):
        CiNN(**{**TINY, "actnorm": "no"})
