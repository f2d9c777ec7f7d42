"""Gyro and Accel refuse a repeated timestamp among their valid samples.

Found by outside testing (rig11): an IMU log with every stamp written twice (a logger's
bug) was accepted silently, each reading counted as two independent measurements (the
solve converged, chi2/dof 0.94, nothing said). Sorted but repeated times stay legal where
they mean something (several corners of one frame, several pairs from one keyframe), so the
check is the inertial terms' own; masked samples may repeat anything.
"""

import numpy as np
import pytest
import torch
from _rig11_rig import accel, gyro

from torch_dq.fitting import Accel, Gyro

TI = np.arange(0.0, 1.0, 0.01)


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))


@pytest.mark.parametrize("kind, truth", [(Gyro, gyro), (Accel, accel)])
def test_a_repeated_stamp_is_refused_naming_the_sample(kind, truth):
    t = TI.copy()
    t[7] = t[6]  # sorted, one stamp twice
    with pytest.raises(ValueError, match=rf"{kind.__name__}: times must be strictly "
                                         r"increasing.*sample 7 is not"):
        kind(_t(t), _t(truth(t)), sigma=0.01)


def test_every_stamp_twice_is_refused():
    t = np.repeat(TI, 2)
    with pytest.raises(ValueError, match="sample 1 is not"):
        Gyro(_t(t), _t(gyro(t)), sigma=0.01)


def test_a_repeat_in_one_row_of_a_batch_names_the_row():
    t = np.stack([TI, TI])
    t[1, 20] = t[1, 19]
    r = np.stack([gyro(TI), gyro(TI)])
    with pytest.raises(ValueError, match=r"sample 20 of batch element \[1\]"):
        Gyro(_t(t), _t(r), sigma=0.01)


def test_masked_samples_may_repeat_and_precede_the_first_valid_one():
    """Padding (zeros at the end, a masked repeat, masked samples before the first valid
    one) is no repeat of a valid stamp."""
    t = np.concatenate([[0.0, 0.0], TI[:50], [TI[49], 0.0, 0.0]])
    mask = torch.ones(len(t), dtype=torch.bool)
    mask[:2] = False
    mask[-3:] = False
    term = Gyro(_t(t), _t(gyro(t)), sigma=0.01, mask=mask)
    assert int(term.mask.sum()) == 50
    t2 = np.stack([TI, TI])
    t2[1, -1] = t2[1, -2]  # the repeat masked in that row only
    mask2 = torch.ones(t2.shape, dtype=torch.bool)
    mask2[1, -1] = False
    Accel(_t(t2), _t(np.stack([accel(TI), accel(TI)])), sigma=0.01, mask=mask2)


def test_random_walk_terms_check_the_readings_not_their_ties():
    """calibration's random-walk biases add a pseudo-sample at each inner segment edge, which
    may fall on a reading's time: allowed; a repeated reading is not."""
    from torch_dq.calibration._walk import WalkGyro

    edges = _t([0.0, 0.5, 1.0])  # 0.5 is a reading's time
    args = dict(sigma=0.01, edges=edges, walk=0.01, starts=torch.zeros(2, 3, dtype=torch.float64))
    WalkGyro(_t(TI), _t(gyro(TI)), **args)
    t = TI.copy()
    t[31] = t[30]
    with pytest.raises(ValueError, match=r"camera_imu \(gyroscope\): times must be strictly"):
        WalkGyro(_t(t), _t(gyro(t)), **args)
