"""A small Segment Anything with random weights, built from `segment_anything`'s own
modules as `build_sam` wires them (LayerNorm eps 1e-6, relative positions, windowed and
global blocks; a window that does not divide the grid, so padding is exercised), and its
outputs on a random input for tests/parity.rs: OUT/sam.safetensors (the weights) and
OUT/reference.safetensors (input, image embedding, masks and IoU per prompt, masks
scaled back to a photograph's size)."""

import json
import sys
from functools import partial
from pathlib import Path

import torch
from safetensors.torch import save_file
from segment_anything.modeling import (
    ImageEncoderViT,
    MaskDecoder,
    PromptEncoder,
    Sam,
    TwoWayTransformer,
)

out = Path(sys.argv[1])
torch.manual_seed(0)
IMG, DIM, PROMPT_DIM = 128, 64, 32
grid = IMG // 16
sam = Sam(
    image_encoder=ImageEncoderViT(
        depth=3,
        embed_dim=DIM,
        img_size=IMG,
        mlp_ratio=4,
        norm_layer=partial(torch.nn.LayerNorm, eps=1e-6),
        num_heads=2,
        patch_size=16,
        qkv_bias=True,
        use_rel_pos=True,
        global_attn_indexes=[1],
        window_size=3,
        out_chans=PROMPT_DIM,
    ),
    prompt_encoder=PromptEncoder(
        embed_dim=PROMPT_DIM,
        image_embedding_size=(grid, grid),
        input_image_size=(IMG, IMG),
        mask_in_chans=16,
    ),
    mask_decoder=MaskDecoder(
        num_multimask_outputs=3,
        transformer=TwoWayTransformer(depth=2, embedding_dim=PROMPT_DIM, mlp_dim=64, num_heads=8),
        transformer_dim=PROMPT_DIM,
        iou_head_depth=3,
        iou_head_hidden_dim=32,
    ),
).eval()
# A fresh model has zero positions and unit norms: make every parameter random.
g = torch.Generator().manual_seed(1)
with torch.no_grad():
    for name, p in sam.named_parameters():
        if "norm" in name or "pos" in name or name.endswith("bias"):
            base = 1.0 if ("norm" in name and name.endswith("weight")) else 0.0
            p.copy_(base + 0.3 * torch.randn(p.shape, generator=g))
save_file({k: v.contiguous() for k, v in sam.state_dict().items()}, str(out / "sam.safetensors"))

x = torch.randn((1, 3, IMG, IMG), generator=g)
prompts = [
    {"points": [[40.0, 70.5, 1]], "box": None},
    {"points": [[20.0, 30.0, 1], [100.0, 90.0, 0]], "box": [10.0, 12.0, 110.0, 96.0]},
    {"points": [], "box": [30.0, 40.0, 80.0, 120.0]},
]
ref = {"input": x}
with torch.no_grad():
    emb = sam.image_encoder(x)
    ref["embedding"] = emb
    for i, p in enumerate(prompts):
        pts = None
        if p["points"]:
            c = torch.tensor([[q[:2] for q in p["points"]]], dtype=torch.float)
            l = torch.tensor([[q[2] for q in p["points"]]], dtype=torch.int)
            pts = (c, l)
        box = torch.tensor([p["box"]], dtype=torch.float) if p["box"] else None
        sparse, dense = sam.prompt_encoder(points=pts, boxes=box, masks=None)
        for multi in (False, True):
            masks, iou = sam.mask_decoder(
                image_embeddings=emb,
                image_pe=sam.prompt_encoder.get_dense_pe(),
                sparse_prompt_embeddings=sparse,
                dense_prompt_embeddings=dense,
                multimask_output=multi,
            )
            ref[f"masks_{i}_{int(multi)}"] = masks
            ref[f"iou_{i}_{int(multi)}"] = iou
            if multi:
                # A 100 × 70 photograph: resized to 128 × 90 (ResizeLongestSide's rounding).
                ref[f"full_{i}"] = sam.postprocess_masks(masks, (90, 128), (70, 100))
save_file({k: v.contiguous() for k, v in ref.items()}, str(out / "reference.safetensors"))
(out / "prompts.json").write_text(json.dumps(prompts))
