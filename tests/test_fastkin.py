"""The compiled FK kernel against the NumPy reference: DH and MDH, Hayati's beta, prismatic
joints, base and tool, non-geometric terms, to 1e-12; its sine/cosine; and the ``fk`` backend
dispatch. Numba is optional (the ``fast`` extra): without it this module is skipped, and
``tests/test_nongeometric.py`` checks the error a ``backend="numba"`` call raises."""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from conftest import random_q

pytest.importorskip("numba", reason="Numba is optional (pip install relcal[fast])")

from relcal import geometry as tf  # noqa: E402
from relcal.robot import fastkin, kinematics  # noqa: E402
from relcal.robot.kinematics import fk  # noqa: E402
from relcal.robot.loading import get_robot  # noqa: E402
from relcal.robot.model import auto_hayati, library_names  # noqa: E402


def everything(model, rng):
    """Random betas, a prismatic joint, base and tool: every branch of the kernel."""
    n = model.n_joints
    prismatic = np.zeros(n, dtype=bool)
    prismatic[2] = True
    return replace(
        auto_hayati(model),
        theta_off=rng.normal(0, 0.5, n),
        beta=rng.normal(0, 0.1, n),
        prismatic=prismatic,
        base=tf.from_vector(rng.normal(0, 0.3, 6)),
        tool=tf.from_vector(rng.normal(0, 0.3, 6)),
    )


@pytest.mark.parametrize("name", ["a465", "puma560", "ur5e", "franka_fr3", "irb120"])
@pytest.mark.parametrize("variant", ["nominal", "everything"])
def test_kernel_matches_numpy(name, variant, rng):
    if name not in library_names():
        pytest.skip(f"robot {name} not in the library")
    model = get_robot(name)
    if variant == "everything":
        model = everything(model, rng)
    # More than one block, and a partial last block.
    q = random_q(model, 2 * fastkin.BLOCK + 37, rng, scale=1.0)
    np.testing.assert_allclose(
        fastkin.fk(model, q), fk(model, q, backend="numpy"), rtol=0, atol=1e-12
    )


@pytest.mark.parametrize("convention", ["dh", "mdh"])
def test_kernel_zero_and_one_configuration(convention, a465):
    model = replace(a465, convention=convention)
    assert fastkin.fk(model, np.zeros((0, 6))).shape == (0, 4, 4)
    q = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
    np.testing.assert_allclose(fastkin.fk(model, q)[0], fk(model, q, "numpy"), atol=1e-12)


def test_kernel_rejects_wrong_joint_count(a465):
    with pytest.raises(ValueError, match=r"shape \(N, 6\)"):
        fastkin.fk(a465, np.zeros((3, 7)))


def test_sincos_matches_libm(rng):
    x = np.concatenate(
        [
            rng.uniform(-50, 50, 100_000),
            np.arange(-40, 41) * np.pi / 4,  # quadrant boundaries
            [0.0, -0.0, 1e-300, np.pi / 2, -np.pi, 1e4],
        ]
    )
    s, c = fastkin.sin_cos(x)
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=4e-16)
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=4e-16)


def test_backends_agree_and_auto_dispatch(a465, rng):
    q = random_q(a465, 50, rng)
    reference = fk(a465, q, backend="numpy")
    np.testing.assert_allclose(fk(a465, q, backend="numba"), reference, atol=1e-12)
    np.testing.assert_allclose(fk(a465, q, backend="auto"), reference, atol=1e-12)
    assert np.array_equal(fk(a465, q), reference)  # the default is the NumPy path
    with pytest.raises(ValueError, match="backend: unknown str 'fortran'"):
        fk(a465, q, backend="fortran")
    # "auto" decides by batch size only, so every process rounds a given call the same way.
    assert not kinematics._use_fast("auto", kinematics._LOAD_MIN - 1)
    assert kinematics._use_fast("auto", kinematics._LOAD_MIN)


def test_backends_agree_with_nongeometric_terms(a465, rng):
    from relcal.robot.model import with_loads, with_nongeometric

    model = with_loads(a465, mass=np.full(6, 2.0), com=rng.normal(0, 0.05, (6, 3)))
    model = with_nongeometric(model, ["scale", "compliance", "harmonic"])
    model = replace(
        model,
        scale=rng.normal(0, 1e-3, 6),
        compliance=rng.normal(0, 1e-4, 6),
        harmonic_c=rng.normal(0, 1e-3, 6),
        harmonic_s=rng.normal(0, 1e-3, 6),
    )
    q = random_q(model, 2 * fastkin.BLOCK + 5, rng)
    reference = fk(model, q, backend="numpy")
    assert np.abs(reference - fk(a465, q)).max() > 1e-5  # the terms matter
    np.testing.assert_allclose(fk(model, q, backend="numba"), reference, rtol=0, atol=1e-12)


def test_small_batches_do_not_import_numba():
    # Short commands must start without Numba's import (and never trigger a compile).
    code = (
        "import sys, numpy as np; from relcal.robot.kinematics import fk; "
        "from relcal.robot.loading import "
        "get_robot; fk(get_robot('a465'), np.zeros((500, 6))); print('numba' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
