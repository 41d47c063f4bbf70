"""kernels.space.params.Slots: the one naming scheme of every parameter array, and the
device policy the grids are built with."""

import numpy as np
import pytest

from flocklab.kernels.runtime import DevicePolicy
from flocklab.kernels.space.params import Slots


def test_slots_number_names_in_order_and_blocks_after_them():
    lead = Slots("PX", "PY", "A00")
    p = Slots("FA", "FB", "DT", LEAD=3 * lead.size)
    assert (p.FA, p.FB, p.DT, p.LEAD) == (0, 1, 2, 3)
    assert p.size == 3 + 9
    assert (lead.PX, lead.PY, lead.A00, lead.size) == (0, 1, 2, 3)


def test_pack_sets_named_slots_and_zeroes_the_rest():
    p = Slots("DT", "A", "C", "R2")
    prm = p.pack(A=2.5, R2=4.0)
    assert prm.dtype == np.float64
    assert prm.tolist() == [0.0, 2.5, 0.0, 4.0]
    with pytest.raises(KeyError):
        p.pack(B=1.0)


@pytest.mark.parametrize("names", [("DT", "DT"), ("size",), ("pack",)])
def test_a_slot_name_twice_or_reserved_is_refused(names):
    with pytest.raises(ValueError, match="declared twice or reserved"):
        Slots(*names)


def test_device_policy_per_backend():
    assert DevicePolicy.for_backend("cpu") == DevicePolicy(serial_scatter=True, dense_grid=True)
    for gpu in ("cuda", "vulkan"):
        assert DevicePolicy.for_backend(gpu) == DevicePolicy(serial_scatter=False,
                                                             dense_grid=False,
                                                             cell_blocks=False)
