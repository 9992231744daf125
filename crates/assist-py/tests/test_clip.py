"""assist.Clip against the reference implementations: small, randomly initialised CLIPs
built with open_clip and with Hugging Face transformers, saved as safetensors, must give
the same token ids and the same image and text features (to 1e-4) in assist."""

import gzip
import importlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import assist



def need(module):
    """The reference libraries: required in CI (ASSIST_REQUIRE_PYTHON), else a loud skip."""
    if os.environ.get("ASSIST_REQUIRE_PYTHON"):
        return importlib.import_module(module)
    return pytest.importorskip(module, reason=f"the CLIP parity tests need {module} (CI installs it)")


torch = need("torch")
open_clip = need("open_clip")
transformers = need("transformers")
save_file = need("safetensors.torch").save_file

PHRASES = [
    "a red ceramic mug",
    "the thing you drink from",
    "A Yellow Rubber DUCK, on the desk!",
    "teapot #3 at 45°  (blue)",
    "it's the robot's hand &amp; arm",
    "naïve café crème",
    "x " * 100,  # longer than the context: cut, ending in the end-of-text token
    "",
]

VOCAB = Path(open_clip.__file__).parent / "bpe_simple_vocab_16e6.txt.gz"


def randomize(model, seed):
    """Random layer norms and biases too (a fresh model has ones and zeros there)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if p.ndim == 1 and ("ln" in name or "norm" in name or name.endswith("bias")):
                base = 1.0 if name.endswith("weight") else 0.0
                p.copy_(base + 0.2 * torch.randn(p.shape, generator=g))
    return model.eval()


def open_clip_model(tmp_path, quick_gelu, seed=0):
    torch.manual_seed(seed)
    vision = dict(image_size=64, layers=2, width=128, patch_size=16, head_width=32)
    text = dict(context_length=77, vocab_size=49408, width=64, heads=2, layers=2)
    model = open_clip.model.CLIP(
        embed_dim=48, vision_cfg=vision, text_cfg=text, quick_gelu=quick_gelu
    )
    randomize(model, seed)
    d = tmp_path / f"open_clip_{int(quick_gelu)}"
    d.mkdir()
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, d / "open_clip_model.safetensors")
    mean, std = [0.5, 0.4, 0.3], [0.2, 0.25, 0.3]
    cfg = {
        "model_cfg": {"embed_dim": 48, "quick_gelu": quick_gelu, "vision_cfg": vision, "text_cfg": text},
        "preprocess_cfg": {"mean": mean, "std": std},
    }
    (d / "open_clip_config.json").write_text(json.dumps(cfg))
    shutil.copy(VOCAB, d / VOCAB.name)
    return model, d, mean, std


def close(a, b, tol=1e-4):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape, (a.shape, b.shape)
    err = np.abs(a - b).max()
    assert err <= tol, f"max |difference| {err:.3g} > {tol}"
    return err


def test_tokens_equal_open_clips(tmp_path):
    tok = open_clip.get_tokenizer("ViT-B-32")
    ref = tok(PHRASES).numpy()
    _, path, _, _ = open_clip_model(tmp_path, False)
    clip = assist.Clip(path)
    for i, p in enumerate(PHRASES):
        assert list(clip.tokenize(p)) == list(ref[i]), p


@pytest.mark.parametrize("quick_gelu", [False, True])
def test_features_equal_open_clips(tmp_path, quick_gelu):
    model, path, mean, std = open_clip_model(tmp_path, quick_gelu, seed=1 + quick_gelu)
    clip = assist.Clip(path)
    c = clip.config
    assert (c["image_size"], c["patch_size"], c["vision_heads"], c["text_heads"]) == (64, 16, 4, 2)
    assert c["quick_gelu"] == quick_gelu and c["layout"] == "OpenClip"

    tok = open_clip.get_tokenizer("ViT-B-32")
    with torch.no_grad():
        want = model.encode_text(tok(PHRASES)).numpy()
    close(clip.encode_text(PHRASES), want)
    close(
        clip.encode_text(PHRASES, normalize=True),
        want / np.linalg.norm(want, axis=1, keepdims=True),
    )

    # Preprocessed pixels.
    x = torch.randn(5, 3, 64, 64, generator=torch.Generator().manual_seed(7))
    with torch.no_grad():
        want = model.encode_image(x).numpy()
    close(clip.encode_image(x.numpy()), want)

    # uint8 images at the model's size: the same normalisation as open_clip's transform.
    from PIL import Image

    rng = np.random.default_rng(3)
    imgs = rng.integers(0, 256, (3, 64, 64, 3), dtype=np.uint8)
    pre = open_clip.image_transform(64, is_train=False, mean=mean, std=std)
    with torch.no_grad():
        want = model.encode_image(torch.stack([pre(Image.fromarray(i)) for i in imgs])).numpy()
    close(clip.encode_image(imgs), want)
    close(clip.encode_image(imgs[0])[0], want[0])

    # Other sizes are resized (bicubic) and centre-cropped as open_clip does; the
    # resampling kernels differ in rounding (PIL's fixed point), so only closeness is
    # asked: cosine ≥ 0.99 for smooth images.
    yy, xx = np.mgrid[0:90, 0:150]
    smooth = np.stack([xx * 1.5, yy * 2.5, (xx + yy)], -1).clip(0, 255).astype(np.uint8)
    with torch.no_grad():
        want = model.encode_image(pre(Image.fromarray(smooth))[None]).numpy()[0]
    got = clip.encode_image(smooth)[0]
    cos = got @ want / np.linalg.norm(got) / np.linalg.norm(want)
    assert cos > 0.99, cos


def test_features_equal_transformers(tmp_path):
    torch.manual_seed(4)
    cfg = transformers.CLIPConfig(
        text_config=dict(
            hidden_size=64, intermediate_size=160, num_hidden_layers=2, num_attention_heads=4,
            max_position_embeddings=77, vocab_size=49408,
        ),
        vision_config=dict(
            hidden_size=96, intermediate_size=200, num_hidden_layers=2, num_attention_heads=3,
            image_size=48, patch_size=12,
        ),
        projection_dim=40,
    )
    model = randomize(transformers.CLIPModel(cfg), 4)
    d = tmp_path / "hf"
    model.save_pretrained(d, safe_serialization=True)
    merges = gzip.open(VOCAB).read().decode("utf-8").split("\n")[1 : 49152 - 256 - 2 + 1]
    (d / "merges.txt").write_text("#version: 0.2\n" + "\n".join(merges) + "\n")
    clip = assist.Clip(d)
    c = clip.config
    assert c["layout"] == "HuggingFace" and c["quick_gelu"] and c["vision_heads"] == 3

    ids = open_clip.get_tokenizer("ViT-B-32")(PHRASES)
    x = torch.randn(4, 3, 48, 48, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        t = model.get_text_features(input_ids=ids)
        i = model.get_image_features(pixel_values=x)
    t = getattr(t, "pooler_output", t).numpy()
    i = getattr(i, "pooler_output", i).numpy()
    close(clip.encode_text(PHRASES), t)
    close(clip.encode_image(x.numpy()), i)


def test_bad_files_are_named(tmp_path):
    _, path, _, _ = open_clip_model(tmp_path, False)
    w = path / "open_clip_model.safetensors"
    data = w.read_bytes()

    w.write_bytes(data[: len(data) // 2])
    with pytest.raises(assist.AssistError, match=r"open_clip_model.safetensors.*truncated"):
        assist.Clip(path)

    w.write_bytes(data)
    (path / "bpe_simple_vocab_16e6.txt.gz").unlink()
    with pytest.raises(assist.AssistError, match="no BPE vocabulary"):
        assist.Clip(path)

    with pytest.raises(assist.AssistError, match="does not exist"):
        assist.Clip(tmp_path / "nowhere")


def test_scene_phrases_resolve_by_meaning(trained, tmp_path, monkeypatch):
    """A scene embedded with an open_clip model: a phrase no label matches is resolved by
    meaning through the session (ASSIST_CLIP), or refused with the candidates' scores."""
    from conftest import run

    _, scene, _ = trained
    copy = tmp_path / "s.assist"
    shutil.copytree(scene, copy)
    _, clip_dir, _, _ = open_clip_model(tmp_path, True, seed=9)
    run("embed", copy, "--clip", clip_dir)
    monkeypatch.setenv("ASSIST_CLIP", str(clip_dir))
    s = assist.Scene.load(copy)
    assert all(len(n["embedding"]) == 48 for n in s.nodes)
    try:
        actions = s.apply("move the drinking vessel left 5 cm")
        assert actions and actions[0]["instance_id"] in [n["id"] for n in s.nodes]
    except assist.AssistError as e:
        assert "too close to call by meaning" in str(e), e
    monkeypatch.delenv("ASSIST_CLIP")
    s = assist.Scene.load(copy)
    with pytest.raises(assist.AssistError, match="ASSIST_CLIP"):
        s.apply("move the drinking vessel left 5 cm")
