"""FitResult.mjcf_inertial / urdf_inertial, read back by MuJoCo and by an XML parser; the CLI's exports and JSON."""

import dataclasses
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from reference import imu_noise, reference_rotation, to_body

import rbjax as rb

# an asymmetric body with products of inertia (kg m²), tumbling near its intermediate axis
I_TRUE = np.array([[1.0, 0.1, -0.05], [0.1, 2.0, 0.08], [-0.05, 0.08, 2.6]]) * 1e-4
TRACE = float(np.trace(I_TRUE))
MASS = 0.2


@pytest.fixture(scope="module")
def fit():
    t = np.linspace(0.0, 2.0, 401)
    q, w = reference_rotation(I_TRUE, np.array([1.0, 0, 0, 0]), np.array([0.3, 3.0, 0.4]), t)
    qn, wn = imu_noise(q, to_body(q, w), np.random.default_rng(4), sq=1e-4, sw=1e-3)
    res = rb.fit_inertia(t, qn, body_rates=wn)
    assert not res.scale_fixed and bool(res.converged)
    return res


def _quat_matrix(q):
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _mujoco_inertia(inertial: str):
    """(mass, full inertia tensor) MuJoCo compiles from one body with this <inertial>: R(iquat) diag R(iquat)ᵀ."""
    mujoco = pytest.importorskip("mujoco")
    xml = f'<mujoco><worldbody><body name="b"><freejoint/>{inertial}</body></worldbody></mujoco>'
    m = mujoco.MjModel.from_xml_string(xml)
    R = _quat_matrix(m.body_iquat[1])
    return float(m.body_mass[1]), R @ np.diag(m.body_inertia[1]) @ R.T


@pytest.mark.parametrize("diagonal", [False, True], ids=["fullinertia", "diaginertia+quat"])
def test_mjcf_inertial_is_the_fitted_inertia_as_mujoco_reads_it(fit, diagonal):
    pytest.importorskip("mujoco")
    expected = TRACE * np.asarray(fit.inertia, np.float64)
    mass, I = _mujoco_inertia(fit.mjcf_inertial(MASS, TRACE, diagonal=diagonal))
    assert mass == MASS
    assert np.linalg.norm(I - expected) / np.linalg.norm(expected) < 1e-9
    assert np.linalg.norm(I - I_TRUE) / np.linalg.norm(I_TRUE) < 0.01  # and it is the body's


def test_urdf_inertial_holds_the_six_entries(fit):
    expected = TRACE * np.asarray(fit.inertia, np.float64)
    el = ET.fromstring(fit.urdf_inertial(MASS, TRACE, xyz=(0.0, 0.01, 0.0)))
    assert el.tag == "inertial" and float(el.find("mass").get("value")) == MASS
    assert [float(v) for v in el.find("origin").get("xyz").split()] == [0.0, 0.01, 0.0]
    got = {k: float(v) for k, v in el.find("inertia").attrib.items()}
    for name, (i, j) in dict(ixx=(0, 0), ixy=(0, 1), ixz=(0, 2), iyy=(1, 1), iyz=(1, 2), izz=(2, 2)).items():
        assert abs(got[name] - expected[i, j]) <= 1e-12 * abs(expected[i, j]), name


def test_exports_refuse_what_they_cannot_write(fit):
    # a normalised fit (tr I = 1) without the scale: the user is told what to pass
    with pytest.raises(ValueError, match=r"FitResult.mjcf_inertial: .*normalised to tr I = 1.*pass scale=tr I"):
        fit.mjcf_inertial(MASS)
    with pytest.raises(ValueError, match=r"FitResult.urdf_inertial: .*pass scale="):
        fit.urdf_inertial(MASS)
    with pytest.raises(ValueError, match="mass must be finite and > 0"):
        fit.urdf_inertial(-1.0, TRACE)
    absolute = dataclasses.replace(fit, scale_fixed=True)  # as a fit with torques reports it
    with pytest.raises(ValueError, match="already in kg m²"):
        absolute.mjcf_inertial(MASS, TRACE)
    el = ET.fromstring(absolute.urdf_inertial(MASS))
    assert float(el.find("inertia").get("izz")) == float(np.asarray(fit.inertia)[2, 2])


def _csv(tmp_path, I=I_TRUE, seconds=1.0, seed=0):
    """A torque-free recording (scipy's DOP853, small noise) as the CLI's CSV."""
    t = np.linspace(0.0, seconds, int(200 * seconds) + 1)
    q, w = reference_rotation(I, np.array([1.0, 0, 0, 0]), np.array([1.0, 0.3, -2.0]), t)
    qn, wn = imu_noise(q, to_body(q, w), np.random.default_rng(seed), sq=1e-4, sw=1e-3)
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([t, qn, wn]), delimiter=",", header="t,qw,qx,qy,qz,gx,gy,gz", comments="")
    return path


def _check_report(res):
    """The JSON's principal moments, axes and covariance against what they must be for its own inertia."""
    I = np.asarray(res["inertia"])
    moments, axes, cov = (np.asarray(res[k]) for k in ("principal_moments", "principal_axes", "inertia_covariance"))
    np.testing.assert_allclose(moments, np.linalg.eigvalsh(I), rtol=0, atol=1e-12 * np.trace(I))
    np.testing.assert_allclose(axes.T @ axes, np.eye(3), atol=1e-12)  # columns: orthonormal axes ...
    np.testing.assert_allclose(I @ axes, axes * moments, atol=1e-12 * np.trace(I))  # ... of the inertia, in order
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T, rtol=0, atol=1e-12 * np.abs(cov).max())
    # moment k's variance is aᵀ C a, a = (v_x², v_y², v_z², 2 v_x v_y, 2 v_x v_z, 2 v_y v_z) of its axis v
    for k in range(3):
        v = axes[:, k]
        a = np.array([v[0] ** 2, v[1] ** 2, v[2] ** 2, 2 * v[0] * v[1], 2 * v[0] * v[2], 2 * v[1] * v[2]])
        np.testing.assert_allclose(np.sqrt(a @ cov @ a), res["moment_std"][k], rtol=1e-6)
    assert len(res["principal_axes_std"]) == 3 and all(s > 0 for s in res["principal_axes_std"])
    for k in ("converged", "solver_converged", "model_consistent", "well_determined", "on_boundary"):
        assert isinstance(res[k], bool), k
    assert 0 <= res["consistency_pvalue"] <= 1 and res["dof"] > 0 and res["chi2"] > 0


def test_cli_writes_mjcf_and_urdf_of_the_fit_in_its_json(tmp_path, capsys):
    import json

    from rbjax._cli import main

    rec, out, mjcf, urdf = _csv(tmp_path), tmp_path / "fit.json", tmp_path / "in.xml", tmp_path / "in.urdf"
    args = ["fit", str(rec), "--out", str(out), "--mjcf", str(mjcf), "--urdf", str(urdf), "--mass", "0.2"]
    assert main([*args, "--scale", str(TRACE)]) == 0
    res = json.loads(out.read_text())
    _check_report(res)
    expected = TRACE * np.asarray(res["inertia"])
    el = ET.fromstring(urdf.read_text())
    got = el.find("inertia").attrib
    assert float(el.find("mass").get("value")) == 0.2
    np.testing.assert_allclose([float(got[k]) for k in ("ixx", "iyy", "izz")], np.diag(expected), rtol=1e-12)
    try:
        import mujoco  # noqa: F401
    except ImportError:
        return  # reading the MJCF back needs mujoco (the 'bench' extra)
    mass, I = _mujoco_inertia(mjcf.read_text())
    assert mass == 0.2 and np.linalg.norm(I - expected) / np.linalg.norm(expected) < 1e-9


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--mjcf", "{tmp}/a.xml"], "--mjcf needs --mass KG"),
        (["--urdf", "{tmp}/a.urdf", "--mass", "-1"], "--mass must be finite and > 0"),
        (["--mjcf", "{tmp}/no/a.xml", "--mass", "0.2"], "no directory"),
        (["--mjcf", "{tmp}/a.xml", "--mass", "0.2"], "normalised to tr I = 1 (only its ratios are known); "),
    ],
)
def test_cli_export_errors_come_before_the_fit(tmp_path, capsys, extra, message):
    from rbjax._cli import main

    csv = tmp_path / "rec.csv"
    csv.write_text("t,qw,qx,qy,qz,gx,gy,gz\n0,1,0,0,0,0.1,0.2,0.3\n0.01,1,0,0,0,0.1,0.2,0.3\n")
    # two samples: a fit of them would fail; the export's error is said first
    assert main(["fit", str(csv), *[e.format(tmp=tmp_path) for e in extra]]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rbjax: error: ") and err.count("\n") == 1 and message in err
