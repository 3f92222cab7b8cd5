"""Tests of the `reflcap` Python module (cli/python/bindings.cc).

The data come from the library itself: the reflcap executable (REFLCAP_BINARY, set by ctest)
synthesises a small capture, resamples it, fits it and renders its holdout views into a temporary
folder; the module's readers, BRDF, fitter and renderer are checked against those files and
against the Lafortune formula written out here.
"""
import json
import math
import os
import pathlib
import shutil
import subprocess

import numpy as np
import pytest

import reflcap

BINARY = os.environ.get("REFLCAP_BINARY")
SIZE = 96  # photograph width and height
ATLAS = 32  # atlas resolution


def run_reflcap(*args):
    if not BINARY:
        pytest.skip("REFLCAP_BINARY is not set (ctest sets it)")
    subprocess.run([BINARY, *map(str, args), "--quiet"], check=True)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """capture/, samples/ (train split), fit/ and renders/ (holdout split) of a small synth."""
    root = tmp_path_factory.mktemp("reflcap")
    # 216 photographs of 96^2 pixels onto a 32^2 atlas: enough samples per texel for a few dozen
    # texels to fit a lobe of their own (about 4 s in all).
    run_reflcap("synth", "--out", root / "capture", "--texels", 1500, "--image-size", SIZE,
                "--cameras", 3, "--lights", 6, "--steps", 12)
    run_reflcap("resample", root / "capture", "--out", root / "samples", "--atlas-res", ATLAS)
    # --model-choice bic: the default k-fold choice gives most own lobes their material's, and
    # test_read_fit_agrees_with_reflcap_fit needs texels that kept their own fit.
    run_reflcap("fit", root / "samples", "--out", root / "fit", "--backend", "cpu",
                "--model-choice", "bic")
    run_reflcap("render", root / "capture", root / "fit", "--out", root / "renders")
    return root


# ---- Reference formula ------------------------------------------------------------------------

def lafortune_reference(params, wi, wo):
    """f = rho_d / pi + sum_k max(0, Cx wix wox + Cy wiy woy + Cz wiz woz)^n (0 where base <= 0),
    params in the param_names layout, float64."""
    params = np.asarray(params, np.float64)
    lobes = (params.shape[-1] - 3) // 12
    f = np.empty((len(wi), 3))
    for c in range(3):
        f[:, c] = params[..., c] / math.pi
        for k in range(lobes):
            cx, cy, cz, n = (params[..., 3 + 12 * k + 3 * field + c] for field in range(4))
            base = cx * wi[:, 0] * wo[:, 0] + cy * wi[:, 1] * wo[:, 1] + cz * wi[:, 2] * wo[:, 2]
            f[:, c] += np.where(base > 0, np.maximum(base, 0) ** n, 0.0)
    return f


def random_directions(rng, count, min_cos=0.2):
    """Unit vectors in the upper hemisphere with z >= min_cos."""
    out = []
    while len(out) < count:
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        v[2] = abs(v[2])
        if v[2] >= min_cos:
            out.append(v)
    return np.array(out)


def param_vector(rho_d, lobe):
    """One texel's vector (1 lobe): rho_d per channel, lobe = (Cx, Cy, Cz, n) per channel."""
    v = np.zeros(15, np.float32)
    v[:3] = rho_d
    for c in range(3):
        for field in range(4):
            v[3 + 3 * field + c] = lobe[c][field]
    return v


# ---- Captures ---------------------------------------------------------------------------------

def test_read_capture_and_load_image(data):
    cap = reflcap.read_capture(data / "capture" / "capture.json")
    assert len(cap["cameras"]) == 3 and len(cap["lights"]) == 6
    assert len(cap["images"]) == 3 * 6 * 12
    cam = cap["cameras"][0]
    assert cam["K"].shape == (3, 3) and cam["K"][2, 2] == 1.0
    assert (cam["width"], cam["height"]) == (SIZE, SIZE)
    assert cam["R"].shape == (3, 3) and cam["t"].shape == (3,)
    assert cam["pixel_filter"] == "point"  # reflcap synth: one ray per pixel centre
    assert {im["split"] for im in cap["images"]} == {"train", "holdout"}
    assert pathlib.Path(cap["mesh"]).is_file()
    assert set(cap["images"][0]) >= {"file", "camera", "light", "turntable_deg", "split"}
    # A folder names its capture.json too.
    assert reflcap.read_capture(data / "capture")["path"] == cap["path"]

    image = reflcap.load_image(cap, 0)
    assert image.shape == (SIZE, SIZE, 3) and image.dtype == np.float32
    assert np.isfinite(image).all() and image.max() > 0
    np.testing.assert_array_equal(
        image, reflcap.read_exr(data / "capture" / cap["images"][0]["file"]))


# ---- Sample stores ----------------------------------------------------------------------------

def test_read_samples_and_chunks(data):
    store = reflcap.read_samples(data / "samples")
    n = store["sample_count"]
    assert n > 0
    for key in ("wi", "wo", "value", "weight"):
        assert store[key].shape == (n, 3) and store[key].dtype == np.float32, key
    for key in ("texel", "image"):
        assert store[key].shape == (n,) and store[key].dtype == np.uint32, key
    np.testing.assert_allclose(np.linalg.norm(store["wi"], axis=1), 1, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(store["wo"], axis=1), 1, atol=1e-5)
    assert (np.diff(store["texel"].astype(np.int64)) >= 0).all()
    assert store["texel"].max() < store["texels"]
    atlas = store["atlas"]
    assert (atlas["width"], atlas["height"]) == (ATLAS, ATLAS)
    assert atlas["pixel_of_texel"].shape == (store["texels"],)
    assert atlas["pixel_of_texel"].dtype == np.uint32
    offsets = store["offsets"]
    assert offsets.shape == (store["texels"] + 1,) and offsets[-1] == n
    np.testing.assert_array_equal(np.diff(offsets), np.bincount(store["texel"],
                                                                minlength=store["texels"]))
    train = {i for i, im in enumerate(reflcap.read_capture(data / "capture")["images"])
             if im["split"] == "train"}
    assert set(np.unique(store["image"]).tolist()) <= train

    chunk = reflcap.read_chunk(data / "samples", 0)
    m = chunk["wi"].shape[0]
    assert chunk["first_texel"] == 0
    np.testing.assert_array_equal(chunk["wi"], store["wi"][:m])
    np.testing.assert_array_equal(chunk["texel"], store["texel"][:m])
    with pytest.raises(ValueError, match="chunk index"):
        reflcap.read_chunk(data / "samples", store["chunks"])


# ---- BRDF -------------------------------------------------------------------------------------

def test_eval_brdf_matches_the_lafortune_formula():
    rng = np.random.default_rng(7)
    wi = random_directions(rng, 500, 0.05)
    wo = random_directions(rng, 500, 0.05)
    # Two lobes: a mirror lobe and an anisotropic one with a negative Cz, so that many samples have
    # a base <= 0 (lobe cut off).
    params = np.zeros(3 + 24, np.float32)
    params[:3] = [0.5, 0.3, 0.1]
    lobe0 = [(-0.9, -0.9, 0.9, 12.0), (-1.0, -1.0, 1.0, 30.0), (-0.8, -0.7, 0.95, 5.0)]
    lobe1 = [(-1.2, 0.3, -0.2, 2.0), (0.5, -1.5, 0.4, 3.0), (-0.3, -0.3, 0.6, 1.0)]
    for k, lobe in enumerate((lobe0, lobe1)):
        for c in range(3):
            for field in range(4):
                params[3 + 12 * k + 3 * field + c] = lobe[c][field]
    assert reflcap.param_names(2)[3 + 12 + 3 * 3 + 1] == "lobe1.n.G"

    f = reflcap.eval_brdf(params, wi, wo)
    assert f.shape == (500, 3) and f.dtype == np.float32
    np.testing.assert_allclose(f, lafortune_reference(params, wi, wo), rtol=2e-5, atol=1e-6)

    # One parameter row per sample.
    rows = np.repeat(params[None, :], 500, axis=0)
    rows[:, 0] = np.linspace(0, 1, 500)
    np.testing.assert_allclose(reflcap.eval_brdf(rows, wi, wo),
                               lafortune_reference(rows, wi, wo), rtol=2e-5, atol=1e-6)

    # A lobe cut off: base <= 0 gives the Lambert term alone.
    one = param_vector([0.4, 0.4, 0.4], [(-1, -1, 1, 10)] * 3)
    away = reflcap.eval_brdf(one, [0.6, 0.0, 0.8], [0.6, 0.0, 0.8])  # base = -0.36 + 0.64 > 0
    back = reflcap.eval_brdf(one, [0.99, 0.0, 0.141], [0.99, 0.0, 0.141])  # base < 0
    assert away[0, 0] > 0.4 / math.pi
    np.testing.assert_allclose(back, 0.4 / math.pi, rtol=1e-6)

    with pytest.raises(ValueError, match="3 \\+ 12 K"):
        reflcap.eval_brdf(np.zeros(7), wi, wo)
    with pytest.raises(ValueError, match="wo"):
        reflcap.eval_brdf(params, wi, wo[:3])


# ---- Fitting ----------------------------------------------------------------------------------

def synthetic_texels(rng, truths, samples_per_texel=300):
    """Noise-free samples of each texel's BRDF (1 lobe), a quarter of them near the mirror."""
    wi_all, wo_all, value_all, texel_all = [], [], [], []
    for t, truth in enumerate(truths):
        wi = random_directions(rng, samples_per_texel)
        wo = random_directions(rng, samples_per_texel)
        near = slice(0, samples_per_texel // 4)
        mirror = wi[near] * np.array([-1, -1, 1])
        jitter = mirror + rng.normal(scale=0.05, size=mirror.shape)
        wo[near] = jitter / np.linalg.norm(jitter, axis=1, keepdims=True)
        wo[near, 2] = np.maximum(wo[near, 2], 0.2)
        wo[near] /= np.linalg.norm(wo[near], axis=1, keepdims=True)
        wi_all.append(wi)
        wo_all.append(wo)
        value_all.append(lafortune_reference(truth, wi, wo))
        texel_all.append(np.full(samples_per_texel, t, np.uint32))
    return (np.concatenate(wi_all).astype(np.float32), np.concatenate(wo_all).astype(np.float32),
            np.concatenate(value_all).astype(np.float32), np.concatenate(texel_all))


TRUTHS = [
    param_vector([0.5, 0.3, 0.2], [(-0.95, -0.95, 0.95, 40.0)] * 3),
    param_vector([0.2, 0.6, 0.4], [(-1.1, -1.1, 1.1, 15.0), (-1.0, -1.0, 1.0, 25.0),
                                   (-1.05, -1.05, 1.05, 20.0)]),
    param_vector([0.8, 0.8, 0.8], [(-0.9, -0.8, 0.97, 60.0)] * 3),
]


def check_recovered(fit, truths, rng):
    """rho_d within 1 %, n within 3 %, the BRDF within 1 % of its peak on fresh directions."""
    assert fit["params"].shape == (len(truths), 15) and fit["params"].dtype == np.float32
    assert fit["channels"] == reflcap.param_names(1)
    for t, truth in enumerate(truths):
        got = fit["params"][t]
        assert fit["status_names"][fit["status"][t]] in ("converged", "max_iterations")
        np.testing.assert_allclose(got[:3], truth[:3], rtol=0.01)
        np.testing.assert_allclose(got[12:15], truth[12:15], rtol=0.03)
        wi = random_directions(rng, 200)
        wo = random_directions(rng, 200)
        wo[:50] = wi[:50] * np.array([-1, -1, 1])
        expected = lafortune_reference(truth, wi, wo)
        np.testing.assert_allclose(reflcap.eval_brdf(got, wi, wo), expected,
                                   atol=0.01 * expected.max())


@pytest.mark.parametrize("backend", ["cpu", "ceres"])
def test_fit_samples_recovers_known_parameters(backend):
    rng = np.random.default_rng(3)
    wi, wo, value, texel = synthetic_texels(rng, TRUTHS)
    order = rng.permutation(len(texel))  # samples need not be grouped by texel
    fit = reflcap.fit_samples(wi[order], wo[order], value[order], texel=texel[order],
                              backend=backend, lobes=1)
    assert fit["backend"] == backend
    check_recovered(fit, TRUTHS, rng)


def test_fit_samples_on_vulkan_or_a_clear_error():
    rng = np.random.default_rng(5)
    wi, wo, value, texel = synthetic_texels(rng, TRUTHS)
    try:
        fit = reflcap.fit_samples(wi, wo, value, weight=np.ones_like(value), texel=texel,
                                  backend="vulkan")
    except RuntimeError as error:
        assert "ulkan" in str(error)
        pytest.skip(f"no Vulkan device: {error}")
    check_recovered(fit, TRUTHS, rng)


def test_fit_samples_lambert_only_and_bad_options():
    rng = np.random.default_rng(11)
    wi = random_directions(rng, 40).astype(np.float32)
    wo = random_directions(rng, 40).astype(np.float32)
    value = np.tile(np.float32([0.3, 0.2, 0.1]) / np.float32(math.pi), (40, 1))
    fit = reflcap.fit_samples(wi, wo, value, lobes=0)
    assert fit["params"].shape == (1, 3)
    np.testing.assert_allclose(fit["params"][0], [0.3, 0.2, 0.1], rtol=1e-4)
    with pytest.raises(ValueError, match="backend"):
        reflcap.fit_samples(wi, wo, value, backend="gpu")
    with pytest.raises(ValueError, match="same number of rows"):
        reflcap.fit_samples(wi, wo[:5], value)


# ---- Fits and renders of the pipeline ---------------------------------------------------------

def test_read_fit_agrees_with_reflcap_fit(data):
    fit = reflcap.read_fit(data / "fit")
    store = reflcap.read_samples(data / "samples")
    h, w = fit["height"], fit["width"]
    assert (w, h) == (store["atlas"]["width"], store["atlas"]["height"])
    assert fit["lobes"] == 1 and fit["channels"] == reflcap.param_names(1)
    assert fit["params"].shape == (h, w, 15) and fit["params"].dtype == np.float32
    assert fit["sigma"].shape == (h, w, 15)
    status = fit["status"]
    assert {"status", "model", "material_cluster", "lobe_donor", "cost"} <= set(status)
    assert status["status"].shape == (h, w) and status["status"].dtype == np.int32
    assert status["cost"].dtype == np.float32
    assert fit["report"]["texels"] == store["texels"]

    # Texel t lives at pixel_of_texel[t]; pixels of no texel have status -1.
    pixels = store["atlas"]["pixel_of_texel"]
    ys, xs = pixels // w, pixels % w
    assert (status["status"][ys, xs] >= 0).all()
    no_texel = np.ones((h, w), bool)
    no_texel[ys, xs] = False
    assert (status["status"][no_texel] == -1).all()

    # The texels whose parameters are their own fit (model 0 lambert_lobe_absent, 1
    # lambert_no_evidence, 2 own_lobe: not lent a lobe, not albedo-filled) are what fit_samples
    # gives for their samples with the same (default LM) options.
    model = status["model"][ys, xs]
    own = np.isin(model, [0, 1, 2]) & (np.diff(store["offsets"]) > 0)
    texels = np.flatnonzero(own)
    assert len(texels) > 50 and (model[texels] == 2).sum() > 10
    pick = np.isin(store["texel"], texels)
    remap = np.zeros(store["texels"], np.uint32)
    remap[texels] = np.arange(len(texels), dtype=np.uint32)
    ours = reflcap.fit_samples(store["wi"][pick], store["wo"][pick], store["value"][pick],
                               weight=store["weight"][pick], texel=remap[store["texel"][pick]],
                               backend="cpu", lobes=1)
    theirs = fit["params"][ys[texels], xs[texels]]
    np.testing.assert_allclose(ours["params"], theirs, rtol=1e-5, atol=1e-7)  # bit-identical here


def test_render_view_agrees_with_reflcap_render(data):
    cap = reflcap.read_capture(data / "capture")
    holdout = [i for i, im in enumerate(cap["images"]) if im["split"] == "holdout"]
    assert holdout
    for index in holdout[:3]:
        ours = reflcap.render_view(cap, data / "fit", index)
        assert ours.shape == (SIZE, SIZE, 3) and ours.dtype == np.float32
        rendered = data / "renders" / pathlib.Path(cap["images"][index]["file"]).with_suffix(".exr")
        theirs = reflcap.read_exr(rendered)
        assert ours.max() > 0
        np.testing.assert_allclose(ours, theirs, rtol=1e-6, atol=1e-7)
    pixels, mask = reflcap.render_view(data / "capture" / "capture.json", data / "fit" / "params.exr",
                                       holdout[0], mask=True)
    assert mask.shape == (SIZE, SIZE) and 0 < mask.sum() < SIZE * SIZE
    assert (pixels[mask == 0] == 0).all()


# ---- bench/error_by_configuration.py ----------------------------------------------------------

def test_error_by_configuration_accounts_for_every_sample(data, tmp_path):
    """The script's bins hold every usable sample once, and its relative error is the one computed
    here over the whole store at once (it reads chunk by chunk and sums bin by bin)."""
    script = pathlib.Path(__file__).resolve().parents[2] / "bench" / "error_by_configuration.py"
    out = tmp_path / "config.json"
    subprocess.run(["/usr/bin/python3", str(script), str(data / "samples"), str(data / "fit"),
                    "--json", str(out)], check=True, capture_output=True)
    table = json.loads(out.read_text())

    store = reflcap.read_samples(data / "samples")
    fit = reflcap.read_fit(data / "fit")
    wi, wo, y, w = store["wi"], store["wo"], store["value"], store["weight"]
    ok = ((wi[:, 2] > store["min_cos"]) & (wo[:, 2] > store["min_cos"]) &
          np.all(w > 0, axis=1) & np.all(np.isfinite(y), axis=1))
    wi, wo, y = wi[ok], wo[ok], y[ok]
    params = fit["params"].reshape(-1, fit["params"].shape[2])
    f = reflcap.eval_brdf(params[store["atlas"]["pixel_of_texel"][store["texel"][ok]]], wi, wo)
    cos_i = wi[:, 2:3].astype(np.float64)
    expected = math.sqrt(np.sum(((y - f) * cos_i) ** 2) / np.sum((y * cos_i) ** 2))
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    near = int(np.sum(h[:, 2] >= math.cos(math.radians(10))))

    bins = table["bins"]
    assert sum(b["samples"] for b in bins) == ok.sum() > 1000
    assert sum(b["samples"] for b in bins if b["theta_h_near"]) == near > 0
    # Float32 directions and values summed in a different order: 1e-5 is far above that rounding
    # and far below any real change of the error.
    assert table["relative_error"] == pytest.approx(expected, rel=1e-5)
    assert sum(b["error_share"] for b in bins) == pytest.approx(1.0, abs=1e-9)


# ---- Errors name the file ---------------------------------------------------------------------

def test_errors_name_the_file(data, tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.json"):
        reflcap.read_capture(tmp_path / "nowhere.json")
    with pytest.raises(FileNotFoundError, match="store.json|atlas.bin"):
        reflcap.read_samples(tmp_path)
    with pytest.raises(FileNotFoundError, match="params.exr"):
        reflcap.read_fit(tmp_path)

    bad = tmp_path / "capture.json"
    text = (data / "capture" / "capture.json").read_text()
    bad.write_text(text.replace('"exposure_s": ', '"exposure_s": -', 1))
    with pytest.raises(ValueError, match=r"capture\.json.*exposure_s"):
        reflcap.read_capture(bad)

    store = tmp_path / "samples"
    shutil.copytree(data / "samples", store)
    chunk = store / "chunk_00000.rcs"
    chunk.write_bytes(chunk.read_bytes()[:-10])
    with pytest.raises(ValueError, match="chunk_00000.rcs"):
        reflcap.read_samples(store)

    with pytest.raises(ValueError, match=r"capture\.json.*out of range"):
        reflcap.render_view(data / "capture", data / "fit", 999)
