"""Damaged or inconsistent files raise ValueError naming the file and the field."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb


def _traj():
    body = rb.box(jnp.ones(2), jnp.array([[0.1, 0.2, 0.4], [1.0, 2.0, 3.0]]))
    s = rb.State.create(body, angular_velocity=jnp.array([[0.3, 1.0, 0.3], [1.0, 0.0, 0.0]]))
    return rb.simulate(s, None, 0.01, 4, "splitting")


def _saved(tmp_path):
    path = tmp_path / "good.npz"
    rb.save(path, _traj(), method="splitting", dt=0.01)
    with np.load(path) as z:
        return path, {k: z[k] for k in z.files}


def _rewrite(tmp_path, arrays, name="bad.npz"):
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


def test_truncated_and_corrupted_files_name_the_path(tmp_path):
    good, _ = _saved(tmp_path)
    data = good.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"load: .*cut\.npz.*(truncated or corrupted\?)"):
        rb.load(cut)
    # flip bytes inside the first stored member's data: a CRC or decompression failure
    flipped = bytearray(data)
    for i in range(200, 240):
        flipped[i] ^= 0xFF
    bad = tmp_path / "flipped.npz"
    bad.write_bytes(bytes(flipped))
    with pytest.raises(ValueError, match=r"load: .*flipped\.npz"):
        rb.load(bad)
    with pytest.raises(ValueError, match=r"load: .*nothere\.npz does not exist"):
        rb.load(tmp_path / "nothere.npz")
    # a text file is no zip archive; numpy's own advice (allow_pickle) is not passed on
    text = tmp_path / "notes.npz"
    text.write_text("hello")
    with pytest.raises(ValueError, match=r"load: .*notes\.npz as an \.npz archive .*: it is not a zip archive$"):
        rb.load(text)


def test_save_into_a_missing_folder_names_the_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"save: the folder .*nowhere of state\.npz does not exist"):
        rb.save(tmp_path / "nowhere" / "state.npz", _traj())
    assert list(tmp_path.iterdir()) == []  # nothing written, no temporary file left


def test_a_missing_array_is_named(tmp_path):
    _, arrays = _saved(tmp_path)
    del arrays["orientation"]
    with pytest.raises(ValueError, match=r"bad\.npz lacks the array 'orientation' that its metadata lists"):
        rb.load(_rewrite(tmp_path, arrays))


def test_an_extra_array_is_named(tmp_path):
    _, arrays = _saved(tmp_path)
    arrays["junk"] = np.zeros(3)
    with pytest.raises(ValueError, match=r"holds array\(s\) \['junk'\] that its metadata does not describe"):
        rb.load(_rewrite(tmp_path, arrays))


def test_a_three_component_orientation_is_refused(tmp_path):
    _, arrays = _saved(tmp_path)
    arrays["orientation"] = arrays["orientation"][..., :3]
    with pytest.raises(ValueError, match=r"'orientation' has shape \(5, 2, 3\), but State.orientation ends in \(4,\)"):
        rb.load(_rewrite(tmp_path, arrays))


def test_wrong_inertia_shape_and_dtype_and_frame_counts(tmp_path):
    _, arrays = _saved(tmp_path)
    bad = dict(arrays, **{"body.inertia": arrays["body.inertia"][..., :2]})  # (frames, bodies, 3, 2)
    with pytest.raises(ValueError, match=r"'body.inertia' has shape \(5, 2, 3, 2\), but Body.inertia ends in \(3, 3\)"):
        rb.load(_rewrite(tmp_path, bad))
    bad = dict(arrays, position=arrays["position"].astype(np.float32))
    with pytest.raises(ValueError, match=r"'position' has dtype float32, but the metadata records \['float64'\]"):
        rb.load(_rewrite(tmp_path, bad))
    bad = dict(arrays, velocity=arrays["velocity"][:3])
    with pytest.raises(ValueError, match=r"time-stacked fields disagree on the number of frames"):
        rb.load(_rewrite(tmp_path, bad))
    bad = dict(arrays, velocity=arrays["velocity"][:, :1].repeat(3, axis=1))
    with pytest.raises(ValueError, match=r"batch shapes of State's fields do not broadcast"):
        rb.load(_rewrite(tmp_path, bad))


def test_non_unit_quaternion_is_refused_but_a_blown_up_run_loads(tmp_path):
    _, arrays = _saved(tmp_path)
    q = arrays["orientation"].copy()
    q[2, 1] *= 1.01
    with pytest.raises(ValueError, match=r"'orientation' must hold unit quaternions; the worst finite entry is off"):
        rb.load(_rewrite(tmp_path, dict(arrays, orientation=q)))
    # NaN frames (a run that diverged, saved for inspection) are not judged: they load as saved
    q = arrays["orientation"].copy()
    q[3:, 0] = np.nan
    back = rb.load(_rewrite(tmp_path, dict(arrays, orientation=q)))
    assert np.isnan(np.asarray(back.orientation[3:, 0])).all()


def test_malformed_metadata_is_named(tmp_path):
    _, arrays = _saved(tmp_path)
    meta = json.loads(str(arrays["__rbjax__"]))
    del meta["tree"]["fields"]["velocity"]
    bad = dict(arrays, __rbjax__=np.array(json.dumps(meta)))
    with pytest.raises(ValueError, match=r"bad\.npz: the metadata's fields of State are not"):
        rb.load(_rewrite(tmp_path, bad))


def test_a_body_edited_to_no_body_at_all_is_refused_as_the_constructor_refuses_it(tmp_path):
    # a negative mass or an indefinite inertia would load and run, reporting negative kinetic
    # energy: load checks a body with Body's own check, naming the field and the file
    path = tmp_path / "state.npz"
    rb.save(path, rb.State.create(rb.box(2.0, jnp.array([0.1, 0.2, 0.4])), angular_velocity=jnp.array([1.0, 0, 0])))
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    inertia = arrays["body.inertia"]
    cases = [
        ({"body.mass": -arrays["body.mass"]}, r"'body.mass' must be > 0, got \[-2\.\]"),
        ({"body.inertia": inertia * np.array([1.0, 1.0, -1.0])}, r"'body.inertia' must be positive definite"),
        ({"body.inertia": inertia + np.triu(np.full((3, 3), 1e-3), 1)}, r"'body.inertia' must be symmetric"),
        ({"body.inertia": np.diag([1.0, 1.0, 3.0])}, r"'body.inertia''s principal moments .* triangle inequality"),
    ]
    for edit, message in cases:
        bad = _rewrite(tmp_path, dict(arrays, **edit))
        with pytest.raises(ValueError, match=rf"^load: {bad}: {message}.*edited or corrupted"):
            rb.load(bad)
    # a saved Body alone, a trajectory's body (with its time axis), a particle's mass: the same
    rb.save(path, rb.box(2.0, jnp.array([0.1, 0.2, 0.4])))
    with np.load(path) as z:
        body = {k: z[k] for k in z.files}
    with pytest.raises(ValueError, match=r"'inertia' must be positive definite"):
        rb.load(_rewrite(tmp_path, dict(body, inertia=-body["inertia"])))
    _, traj = _saved(tmp_path)
    mass = traj["body.mass"].copy()
    mass[3, 1] = -1.0
    with pytest.raises(ValueError, match=r"'body.mass' must be > 0, got \[-1\.\]"):
        rb.load(_rewrite(tmp_path, dict(traj, **{"body.mass": mass})))
    rb.save(path, rb.ParticleState.create(jnp.array([1.0, 2.0])))
    with np.load(path) as z:
        particles = {k: z[k] for k in z.files}
    with pytest.raises(ValueError, match=r"'mass' must be finite and > 0, got \[0\.\]"):
        rb.load(_rewrite(tmp_path, dict(particles, mass=np.array([1.0, 0.0]))))
    # the files as saved load
    assert float(rb.load(_rewrite(tmp_path, traj)).body.mass[0, 0]) == 1.0
