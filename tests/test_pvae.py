"""The P-VAE: pose features, the dataset built from real motion capture, training, the composite
action (eq. 3.4) and the naturalness reward."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import flax.serialization

from agents import datadir
from agents.commands import cli, pvae_commands
from agents.pose import pose_dataset, pose_features, pvae, pvae_report
from agents.checkpoint import CheckpointError
from agents.config import ConfigError
from jaxsim import characters, kinematics, motion, rotations
from conftest import random_state


@pytest.fixture(scope="module")
def humanoid():
    return characters.humanoid(dtype=jnp.float64)


def test_pose_features_are_root_frame_positions_then_6d_joint_rotations(humanoid):
    q, _, _ = random_state(humanoid, seed=3)
    featurise = jax.jit(lambda q: pose_features.pose_features(humanoid, q))
    features = np.asarray(featurise(q))
    layout = pose_features.PoseLayout.of(humanoid)
    assert features.shape == (layout.feature_size,) == (3 * 14 + 6 * 12,)
    rot, pos = (np.asarray(a) for a in kinematics.forward_kinematics(humanoid, q))
    np.testing.assert_allclose(features[:42].reshape(14, 3), (pos[1:] - pos[0]) @ rot[0],
                               atol=1e-12)
    topo, qn = humanoid.topology, np.asarray(q)
    for k, link in enumerate(layout.actuated):
        start = topo.q_offsets[link]
        if topo.joint_types[link] == "spherical":
            quat = qn[start:start + 4] / np.linalg.norm(qn[start:start + 4])
            expected = np.asarray(rotations.quat_to_matrix(jnp.asarray(quat)))
        else:
            expected = np.asarray(rotations.axis_angle_to_matrix(humanoid.joint_axis[link],
                                                                 qn[start]))
        np.testing.assert_allclose(features[42 + 6 * k: 48 + 6 * k],
                                   np.concatenate([expected[:, 0], expected[:, 1]]), atol=1e-12)
    # Where the character stands and which way it faces does not change its pose features.
    moved = q.at[:3].set(jnp.array([3.0, 0.2, -1.0])).at[3:7].set(
        rotations.axis_angle_to_quat(jnp.array([0.0, 1.0, 0.0]), 2.0))
    np.testing.assert_allclose(featurise(moved), features, atol=1e-12)


def test_decoder_target_round_trips_to_the_joint_targets(humanoid):
    q, _, _ = random_state(humanoid, seed=5)
    target = pose_features.pd_target(humanoid, q)
    assert target.shape == (6 * 8 + 4,)
    pose = pose_features.exp_to_pose(humanoid, pose_features.target_to_exp(humanoid, target),
                                     root=q[:7])
    np.testing.assert_allclose(rotations.quat_to_matrix(_joint_quats(humanoid, pose)),
                               rotations.quat_to_matrix(_joint_quats(humanoid, q)), atol=1e-9)
    revolute = humanoid.topology.q_offsets[humanoid.topology.links_of_type("revolute")]
    np.testing.assert_allclose(pose[revolute], q[revolute], atol=1e-12)
    # Turn one spherical joint (the chest) by 0.3 rad and bend one revolute joint (the right
    # knee) by 0.2 rad: exactly those two joints differ, by those angles.
    topo = humanoid.topology
    chest, knee = topo.q_offsets[topo.link_index("chest")], topo.q_offsets[
        topo.link_index("right_knee")]
    turn = rotations.axis_angle_to_quat(jnp.array([0.0, 0.6, 0.8]), jnp.asarray(0.3))
    moved = q.at[chest:chest + 4].set(rotations.quat_multiply(q[chest:chest + 4], turn))
    moved = moved.at[knee].add(0.2)
    errors = np.asarray(pose_features.joint_angle_errors(
        humanoid, target, pose_features.pd_target(humanoid, moved)))
    layout = pose_features.PoseLayout.of(humanoid)
    expected = np.zeros(len(layout.actuated))
    expected[layout.actuated.index(topo.link_index("chest"))] = 0.3
    expected[layout.actuated.index(topo.link_index("right_knee"))] = 0.2
    np.testing.assert_allclose(errors, expected, atol=1e-6)


def _joint_quats(model, q):
    quats, _ = model.topology.spherical_indices
    return rotations.quat_normalize(q[quats])


@pytest.fixture(scope="module")
def dataset(data_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("pvae") / "poses.npz"
    built, needed = pvae_commands.build_dataset(data_dir, out, echo=lambda *_: None)
    return built, needed, out


def test_dataset_from_cmu_and_deepmimic_has_its_size_and_layout(dataset, data_dir, humanoid):
    built, needed, out = dataset
    names = list(built.clip_names)
    assert len(built) >= 20_000
    assert sum(n.startswith("cmu/") for n in names) == 28
    assert sum(n.startswith("deepmimic/") for n in names) == 20
    assert built.features.shape == (len(built), 114) and built.targets.shape == (len(built), 52)
    assert np.array_equal(np.unique(built.clip_index), np.arange(len(names)))
    # CMU at 120 Hz becomes every fourth frame; a looping DeepMimic clip gives one cycle.
    amc = data_dir / "cmu/02/02_01.amc"
    frames = motion.load_amc(amc, motion.load_asf(data_dir / "cmu/02/02.asf")).n_frames
    assert (built.clip_index == names.index("cmu/02/02_01")).sum() == (frames - 1) // 4 + 1
    walk = motion.load_motion(data_dir / "deepmimic/motions/humanoid3d_walk.txt", humanoid)
    rows = np.flatnonzero(built.clip_index == names.index("deepmimic/humanoid3d_walk"))
    assert len(rows) == int(np.floor(float(walk.duration) * 30 + 1e-9))
    pose = motion.sample_pose(walk, 10 / 30)
    np.testing.assert_allclose(built.features[rows[10]],
                               pose_features.pose_features(humanoid, pose), atol=1e-5)
    # The PCA: about as compact as the thesis's 13 components for 85% of the variance.
    assert 8 <= needed["raw"] <= 20 and needed["standardised"] >= needed["raw"]
    reloaded = pose_dataset.load(out, humanoid)
    np.testing.assert_array_equal(reloaded.features, built.features)
    assert list(reloaded.clip_names) == names


def test_resampling_a_padded_clip_matches_direct_sampling(data_dir, humanoid):
    clip = motion.load_motion(data_dir / "deepmimic/motions/humanoid3d_backflip.txt", humanoid)
    poses = pose_dataset.resample(clip)
    times = jnp.arange(len(poses)) / 30.0
    np.testing.assert_allclose(poses, jax.vmap(lambda t: motion.sample_pose(clip, t))(times),
                               atol=1e-12)


def test_dataset_files_that_do_not_fit_say_why(tmp_path, humanoid, dataset):
    with pytest.raises(pose_dataset.DatasetError, match="no such dataset"):
        pose_dataset.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_text("not an archive")
    with pytest.raises(pose_dataset.DatasetError, match="junk.npz"):
        pose_dataset.load(tmp_path / "junk.npz")
    with pytest.raises(pose_dataset.DatasetError, match="do not fit this character"):
        pose_dataset.load(dataset[2], characters.snake(4))
    with pytest.raises(pose_dataset.DatasetError, match="cmu"):
        list(pose_dataset.source_clips(tmp_path, humanoid))


def test_validation_split_holds_out_whole_clips(dataset):
    built = dataset[0]
    train, held = pose_dataset.split_by_clip(built, 0.1, seed=0)
    assert not np.any(train & held) and np.all(train | held)
    assert set(built.clip_index[train]).isdisjoint(built.clip_index[held])
    assert 0.1 <= held.mean() < 0.25


def test_repeated_clips_weigh_their_training_poses_and_a_pattern_must_match(dataset):
    built = dataset[0]
    names = list(built.clip_names)
    flips = [names.index("deepmimic/humanoid3d_backflip"), names.index("deepmimic/humanoid3d_sideflip")]
    repeats = pose_dataset.pose_repeats(built, ("deepmimic/humanoid3d_*flip",), 7, "poses.npz")
    in_flips = np.isin(built.clip_index, flips)
    assert in_flips.sum() > 50
    assert np.all(repeats[in_flips] == 7) and np.all(repeats[~in_flips] == 1)
    with pytest.raises(pose_dataset.DatasetError, match=r"poses.npz: .*'deepmimic/backflip' "
                                                        r"matches none"):
        pose_dataset.pose_repeats(built, ("deepmimic/backflip",), 7, "poses.npz")
    with pytest.raises(ValueError, match="repeat_count must be at least 1"):
        pvae.DataSettings(repeat_count=0)
    with pytest.raises(ValueError,
                       match=r"go together; got repeat_clips = \[\], repeat_count = 3"):
        pvae.DataSettings(repeat_count=3)
    with pytest.raises(ValueError, match="go together"):
        pvae.DataSettings(repeat_clips=("deepmimic/*",))


@pytest.fixture(scope="module")
def short_run(dataset, tmp_path_factory):
    built, _, path = dataset
    config = pvae.PVAEConfig(train=pvae.TrainSettings(learning_rate=1e-3, epochs=4))
    result = pvae.train(config, built, echo=lambda *_: None)
    out = tmp_path_factory.mktemp("pvae_run")
    pvae.save(result, config, out)
    return config, result, out


def test_short_training_lowers_held_out_error_below_the_mean_pose(short_run, dataset, humanoid):
    config, result, _ = short_run
    held_out = [h["held_out_mse"] for h in result.history]
    assert held_out[-1] < 0.8 * held_out[0]
    errors, n_held = pvae_report.held_out_errors(humanoid, config, dataset[0], result)
    vae = np.mean([v for v, _ in errors.values()])
    mean_pose = np.mean([b for _, b in errors.values()])
    assert n_held > 1000 and vae < 0.6 * mean_pose


def test_composite_target_and_naturalness(short_run, humanoid):
    _, result, out = short_run
    decoder = pvae.load_decoder(out, humanoid)
    latent = jnp.linspace(-1.0, 1.0, 13)
    offset_size = pose_features.PoseLayout.of(humanoid).exp_size
    assert offset_size == 3 * 8 + 4
    base = pvae.composite_target(humanoid, decoder, latent, jnp.zeros(offset_size))
    assert base.shape == (humanoid.nq,)
    trained = pvae.PoseDecoder(result.params, result.normalisation, decoder.network)
    np.testing.assert_allclose(decoder.target(latent), trained.target(latent), atol=1e-6)
    # An offset on a revolute joint (the right knee) moves that angle by exactly the offset.
    layout = pose_features.PoseLayout.of(humanoid)
    knee = humanoid.topology.link_index("right_knee")
    knee_slot = layout.exp_index[1][layout.revolute.index(knee)]
    offset = jnp.zeros(offset_size).at[knee_slot].set(0.3)
    moved = pvae.composite_target(humanoid, decoder, latent, offset)
    at = humanoid.topology.q_offsets[knee]
    assert float(moved[at] - base[at]) == pytest.approx(0.3, abs=1e-9)
    grads = jax.jit(jax.grad(lambda z, o: jnp.sum(pvae.composite_target(humanoid, decoder, z, o)),
                             argnums=(0, 1)))(latent, offset)
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads)
    c = 2.0
    full = jnp.full(offset_size, c / offset_size)
    values = pvae.naturalness(jnp.stack([0 * full, 0.5 * full, full, 3 * full]), c)
    np.testing.assert_allclose(values, [1.0, 0.75, 0.0, 0.0], atol=1e-12)   # 1 − (‖o‖₁/c)²


def test_cli_trains_from_a_config_and_writes_the_report(dataset, tmp_path, capsys):
    built = dataset[0]
    keep = built.clip_index % 6 == 0          # a few whole clips are enough here
    subset = pose_dataset.PoseDataset(built.features[keep], built.targets[keep],
                                      built.poses[keep], built.clip_index[keep],
                                      built.clip_names)
    pose_dataset.save(subset, tmp_path / "subset.npz")
    config = tmp_path / "pvae.toml"
    config.write_text(f'[data]\ndataset = "{tmp_path / "subset.npz"}"\n[train]\nepochs = 2\n')
    assert cli.main(["pvae", "train", str(config), "--out", str(tmp_path / "run"),
                     "--set", "model.latent_size=8", "--set", 'data.repeat_clips=["deepmimic/*"]',
                     "--set", "data.repeat_count=3"]) == 0
    defaults = pvae.DataSettings()
    train_mask, _ = pose_dataset.split_by_clip(subset, defaults.validation_fraction,
                                               defaults.split_seed)
    deepmimic = np.char.startswith(subset.clip_names[subset.clip_index].astype(str), "deepmimic/")
    assert (train_mask & deepmimic).sum() > 0
    per_epoch = train_mask.sum() + 2 * (train_mask & deepmimic).sum()
    printed = capsys.readouterr().out
    assert f"{per_epoch} training poses per epoch, {train_mask.sum()} distinct" in printed
    assert "epoch   2/2" in printed
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    assert report["final"]["epoch"] == 2 and len(report["held_out_joint_error_degrees"]) == 12
    for name in ("pvae.msgpack", "normalisation.npz", "config.json", "losses.png",
                 "joint_errors.png", "samples.png", "report.md"):
        assert (tmp_path / "run" / name).exists(), name
    with pytest.raises(SystemExit, match="run already holds a run; pick another --out"):
        cli.main(["pvae", "train", str(config), "--out", str(tmp_path / "run")])
    with pytest.raises(SystemExit, match="latent_size"):
        cli.main(["pvae", "train", str(config), "--set", "model.latent_size=0"])
    with pytest.raises(ConfigError, match="epochs"):
        pvae_commands.train(config, tmp_path / "x", ["train.epochs=1.5"])


@pytest.mark.parametrize("settings, key, value", [
    (pvae.TrainSettings, "learning_rate", float("nan")), (pvae.TrainSettings, "learning_rate",
                                                          float("inf")),
    (pvae.ModelSettings, "beta", float("nan")), (pvae.ModelSettings, "beta", float("inf"))])
def test_settings_refuse_numbers_that_are_not_finite(settings, key, value):
    with pytest.raises(ValueError, match=f"^{key} must be a finite number"):
        settings(**{key: value})


def _save_small_pvae(humanoid, run_dir):
    """A P-VAE run directory of untrained weights, hidden layers of 8; returns the weights."""
    layout = pose_features.PoseLayout.of(humanoid)
    config = pvae.PVAEConfig(model=pvae.ModelSettings(hidden=(8,)))
    params = pvae.network_of(config, layout.target_size).init(
        jax.random.PRNGKey(0), jnp.zeros((1, layout.feature_size)), jax.random.PRNGKey(1))["params"]
    norm = pvae.Normalisation(jnp.zeros(layout.feature_size), jnp.ones(layout.feature_size),
                              jnp.zeros(layout.target_size), jnp.ones(layout.target_size))
    pvae.save(pvae.TrainResult(params, norm, [], 0.0), config, run_dir)
    return params


def test_weights_that_do_not_fit_name_the_file_and_the_leaf(tmp_path, humanoid):
    params = _save_small_pvae(humanoid, tmp_path)
    assert pvae.load_decoder(tmp_path, humanoid).params["decoder"]["Dense_0"]["kernel"].shape \
        == (13, 8)
    weights = tmp_path / pvae.WEIGHTS_FILE

    def write_changed(change):
        changed = jax.tree_util.tree_map(np.asarray, params)
        change(changed)
        weights.write_bytes(flax.serialization.to_bytes(changed))

    write_changed(lambda p: p["decoder"]["Dense_0"].update(kernel=np.zeros((13, 7), np.float32)))
    with pytest.raises(CheckpointError, match=r"pvae\.msgpack: \['decoder'\]\['Dense_0'\]"
                                              r"\['kernel'\] is float32\[13, 7\] in the file but "
                                              r"this P-VAE's config needs float32\[13, 8\]"):
        pvae.load_decoder(tmp_path, humanoid)
    write_changed(lambda p: p["encoder"]["Dense_1"].update(bias=np.zeros(26)))
    with pytest.raises(CheckpointError, match=r"\['encoder'\]\['Dense_1'\]\['bias'\] is "
                                              r"float64\[26\] in the file"):
        pvae.load_decoder(tmp_path, humanoid)
    write_changed(lambda p: p["decoder"].pop("Dense_1"))
    with pytest.raises(CheckpointError, match=r"pvae\.msgpack: .*Dense_1"):
        pvae.load_decoder(tmp_path, humanoid)


def test_the_data_directory_is_the_one_named_else_the_checkout_default(
        monkeypatch, tmp_path, data_dir):
    monkeypatch.delenv("TAKEOFF_DATA", raising=False)
    assert datadir.data_dir_from() == datadir.checkout_default()   # a checkout needs nothing
    assert datadir.data_dir_from().resolve() == data_dir
    # Installed by copy (no checkout around the package): beside the current directory.
    monkeypatch.setattr(datadir, "_PACKAGE_CHECKOUT", tmp_path / "site-packages")
    (tmp_path / "shared" / "data").mkdir(parents=True)
    (tmp_path / "checkout").mkdir()
    monkeypatch.chdir(tmp_path / "checkout")
    assert datadir.data_dir_from() == tmp_path / "shared" / "data"
    (tmp_path / "shared" / "data").rmdir()
    with pytest.raises(SystemExit, match=r"no data directory at .*shared/data \(the default "
                                         r"beside the checkout\); name it with --data-dir or "
                                         "TAKEOFF_DATA"):
        cli.main(["pvae", "dataset", "--out", str(tmp_path / "poses.npz")])
    monkeypatch.setenv("TAKEOFF_DATA", str(tmp_path / "elsewhere"))
    with pytest.raises(SystemExit, match=r"elsewhere \(TAKEOFF_DATA\)"):
        cli.main(["pvae", "dataset", "--out", str(tmp_path / "poses.npz")])
    assert datadir.data_dir_from(str(data_dir)) == data_dir


def test_files_that_are_not_pose_datasets_are_named_without_pickle_advice(tmp_path):
    n = 3
    arrays = dict(features=np.zeros((n, 4), np.float32), targets=np.zeros((n, 2), np.float32),
                  poses=np.zeros((n, 5), np.float32), clip_index=np.zeros(n, np.int32),
                  clip_names=np.array(["a"]))
    good = tmp_path / "good.npz"
    pose_dataset.save(pose_dataset.PoseDataset(**arrays), good)
    assert len(pose_dataset.load(good)) == n
    (tmp_path / "poses.txt").write_text("0.1 0.2 0.3\n")
    (tmp_path / "empty.npz").write_bytes(b"")
    (tmp_path / "folder.npz").mkdir()
    np.save(tmp_path / "poses.npy", arrays["features"])
    np.savez(tmp_path / "objects.npz", **{**arrays, "features": np.array([{}] * n)})
    np.savez(tmp_path / "flat.npz", **{**arrays, "features": np.zeros(n)})
    np.savez(tmp_path / "partial.npz", features=arrays["features"])
    (tmp_path / "cut.npz").write_bytes(good.read_bytes()[:100])
    damaged = bytearray(good.read_bytes())
    damaged[len(damaged) // 3] ^= 0xFF
    (tmp_path / "damaged.npz").write_bytes(bytes(damaged))
    for name in ("poses.txt", "empty.npz", "folder.npz", "poses.npy", "objects.npz", "flat.npz",
                 "partial.npz", "cut.npz", "damaged.npz"):
        with pytest.raises(pose_dataset.DatasetError) as error:
            pose_dataset.load(tmp_path / name)
        message = str(error.value)
        assert message.startswith(f"{tmp_path / name}: not a pose dataset written by `takeoff "
                                  "pvae dataset`"), message
        assert "pickle" not in message, message


def test_a_normalisation_record_that_is_not_an_npz_archive_is_named(tmp_path, humanoid):
    _save_small_pvae(humanoid, tmp_path)
    record = tmp_path / pvae.NORMALISATION_FILE
    for contents in (b"feature_mean 0 0 0\n", record.read_bytes()[:80]):
        record.write_bytes(contents)
        with pytest.raises(CheckpointError, match=f"^{record}: not the normalisation record of "
                                                  "a P-VAE run") as error:
            pvae.load_decoder(tmp_path, humanoid)
        assert "pickle" not in str(error.value)
