"""assist: editable object-wise neural scenes (ASSIST) — load, edit in words or actions,
render to numpy. Every library error is raised as `AssistError` with its message (the
file, field, value or candidates)."""

from os import PathLike
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, PathLike[str]]
Action = dict[str, Any]

class AssistError(Exception):
    """An error of the assist library (bad file, field, value, unknown object, …)."""

class Camera:
    """Pinhole intrinsics and a 4×4 world-from-camera pose (OpenGL convention: the camera
    looks down −z, y up)."""

    name: str
    split: Optional[str]
    def __init__(
        self,
        pose: npt.NDArray[np.float64],
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        width: int,
        height: int,
        name: str = "camera",
    ) -> None: ...
    @property
    def pose(self) -> npt.NDArray[np.float64]: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels."""

class Dataset:
    """A dataset's cameras (nerfstudio, Blender, COLMAP, LLFF, desk format)."""

    cameras: list[Camera]
    path: str
    @staticmethod
    def load(path: _Path) -> "Dataset": ...
    def __len__(self) -> int: ...

class Clip:
    """A CLIP model from weights on disk: a folder with the model as safetensors
    (open_clip/OpenAI or Hugging Face naming), its BPE vocabulary
    (bpe_simple_vocab_16e6.txt.gz or merges.txt) and open_clip_config.json or
    config.json. `Clip()` reads the folder from ASSIST_CLIP. Features match open_clip's
    `encode_image`/`encode_text` (and transformers' `get_*_features`)."""

    def __init__(self, path: Optional[_Path] = None) -> None: ...
    @property
    def config(self) -> dict[str, Any]:
        """Sizes, heads, activation (quick_gelu), mean/std, logit_scale, files, layout."""
    def tokenize(self, text: str) -> "np.ndarray":
        """Token ids (int64, the context length): start, BPE tokens, end, zeros."""
    def encode_text(self, texts: Sequence[str], normalize: bool = False) -> "np.ndarray":
        """len(texts) × embed_dim float32."""
    def encode_image(self, images: "np.ndarray", normalize: bool = False) -> "np.ndarray":
        """uint8 RGB H×W×3 or n×H×W×3 (resized bicubic, centre-cropped, normalised as
        open_clip's evaluation transform), or float32 n×3×S×S already preprocessed;
        n × embed_dim float32."""

class Scene:
    """A trained scene in memory: nodes, edits with undo and redo, rendering."""

    @staticmethod
    def load(path: _Path, device: str = "cpu") -> "Scene":
        """Opens a NAME.assist scene with its history; its renders query the fields on
        `device`: "cpu" (the reference), "gpu" (a GPU adapter, software ones included; an
        error without one) or "auto" (a hardware GPU when present, else the CPU)."""
    @property
    def device(self) -> str:
        """What queries the fields of this scene's renders: the adapter's name, or "cpu"."""
    @property
    def nodes(self) -> list[dict[str, Any]]:
        """Dicts with id, label, class (semantic class: the label, or for a copy
        "mug 2" the original's "mug"), background (bool), half_size (3,) and pose (4×4
        world-from-box, scale included) and embedding (the node's CLIP embedding, float32,
        or None: see `assist embed`). Instructions resolve object phrases by meaning when
        the scene has embeddings and ASSIST_CLIP names the CLIP weights."""
    @property
    def meters_per_unit(self) -> float: ...
    def apply(self, what: Union[str, Action, Sequence[Action]]) -> list[Action]:
        """Applies an instruction in words or actions as one undo step; returns the
        resolved actions."""
    def plan(self, what: Union[str, Action, Sequence[Action]]) -> list[Action]:
        """What `apply` would do, without applying it."""
    def rename(self, id: int, label: str) -> None:
        """A new label for node `id`, as one undo step; its semantic class stays."""
    def set_scale(
        self,
        node: Optional[str] = None,
        height_m: Optional[float] = None,
        meters_per_unit: Optional[float] = None,
    ) -> float:
        """Metres per world unit from `node` (id or name) being `height_m` metres tall
        along the scene's up, or given directly; one undo step. Returns it."""
    def undo(self) -> bool: ...
    def redo(self) -> bool: ...
    def select(self, id: Optional[int] = None) -> None: ...
    def pick(self, camera: Camera, x: float, y: float) -> Optional[int]:
        """The object seen at pixel (x, y), or None for the background."""
    def add_from(
        self,
        scene_path: _Path,
        node: Union[int, str],
        position: Optional[Sequence[float]] = None,
    ) -> list[Action]: ...
    def save(self, path: _Path, force: bool = False) -> None: ...
    def export(
        self,
        out: _Path,
        nodes: Sequence[str] = ("all",),
        format: str = "obj",
        frame: Optional[str] = None,
        resolution: int = 128,
        density: float = 20.0,
        smooth: float = 1.0,
        triangles: int = 50000,
        min_part: float = 0.05,
        points: int = 100000,
        close: int = 4,
        opacity: float = 0.1,
        sim: Optional[str] = None,
        material_density: float = 1000.0,
        force: bool = False,
    ) -> dict[str, Any]:
        """Meshes (obj, ply, glb) or point clouds (points) of the nodes into the folder
        `out`, as `assist export`; `sim` "mjcf" or "urdf" adds a model. Returns the
        summary: out, model, nodes (id, label, file, vertices, triangles, closed,
        genus, components, volume_m3, occupancy_m3, cut_at_support_m, seconds)."""
    def render(
        self,
        camera: Camera,
        outputs: Sequence[str] = ("rgb", "depth", "instance"),
        width: Optional[int] = None,
        height: Optional[int] = None,
    ) -> dict[str, np.ndarray]:
        """rgb: H×W×3 float32 in [0, 1]; depth: H×W float32 metres; instance: H×W
        uint16 (0 = background); opacity: H×W float32; unseen: H×W bool (no ray met a
        sample: colour and depth continued from the seen pixels around it)."""

def orbit(
    scene: Scene,
    frames: int = 24,
    width: int = 480,
    height: int = 360,
    fov: float = 50.0,
    elevation: float = 30.0,
    radius: Optional[float] = None,
) -> list[Camera]: ...
def cameras(path: _Path, split: str = "all") -> list[Camera]: ...

class Samples:
    """Samples of a generation spec, made on demand; iterate over it."""

    def __iter__(self) -> "Samples": ...
    def __next__(self) -> dict[str, Any]:
        """index, actions, objects, gave_up, and views: each with name, camera, rgb
        (H×W×3 float32), depth (H×W float32 metres), instance and semantic (H×W uint16),
        unobserved (H×W bool: background no training view saw) and annotations."""
    def __len__(self) -> int: ...

def generate(
    spec: Union[_Path, dict[str, Any]],
    seed: Optional[int] = None,
    count: Optional[int] = None,
    start: int = 0,
    device: str = "cpu",
) -> Samples:
    """Samples of a spec (a TOML/JSON file or a dict of the same fields, docs/generate.md),
    without touching the disk; index i is the sample `assist generate` writes as i.
    `device` is where the fields are queried ("cpu", "gpu" or "auto")."""

def process(
    input: _Path,
    out: _Path,
    frames: int = 150,
    matcher: Optional[str] = None,
    cameras: Optional[str] = None,
    scale_by: Optional[str] = None,
    force: bool = False,
    callback: Optional[Callable[[dict[str, Any]], None]] = None,
) -> dict[str, Any]:
    """A video or a folder of photographs → a posed dataset, as `assist process` does
    (Debian's ffmpeg and colmap): matcher "auto", "sequential" or "exhaustive"; cameras
    "shared" (one for the capture, the default) or "per-frame"; scale_by
    "FRAME:x,y FRAME:x,y 0.30m" for metres. The callback sees each event as a dict
    (kind "stage" or "progress"). Ctrl+C stops it and writes nothing. Returns the summary
    (frames, registered, not_registered, matcher, cameras, points, meters_per_unit,
    seconds)."""

def train(
    data: _Path,
    out: _Path,
    max_time: Optional[float] = None,
    iters: Optional[int] = None,
    callback: Optional[Callable[[dict[str, Any]], None]] = None,
    device: str = "cpu",
    **options: Any,
) -> dict[str, Any]:
    """Trains a scene as `assist train` does; options are its flags with `_` for `-`
    (downscale=2, seed=1, resume=True, force=True, shadows="off", lambda_obj_share=0.0,
    …); `device` is where the fields' passes and Adam run ("cpu", "gpu" or "auto"; the
    scene file is the same whichever). The callback sees every event as a dict. Ctrl+C saves the
    scene and raises KeyboardInterrupt. Returns the report (iterations, seconds,
    stopped_by, final_stats)."""

def split(
    scene: _Path,
    out: _Path,
    boxes: list[str] = [],
    clicks: list[str] = [],
    labels: list[str] = [],
    iters: Optional[int] = None,
    max_time: Optional[float] = None,
    data: Optional[_Path] = None,
    masks_out: Optional[_Path] = None,
    no_train: bool = False,
    force: bool = False,
    sam: Optional[_Path] = None,
    callback: Optional[Callable[[dict[str, Any]], None]] = None,
) -> dict[str, Any]:
    """Object nodes cut out of a scene trained without masks, as `assist scene split`
    does: boxes "cx,cy,cz,sx,sy,sz[,yaw]" or clicks "VIEW:u,v", one label each. The
    fine-tune runs `iters` steps (2000; no limit when only `max_time` is given). The
    callback sees each event as a dict (kind "clicked", "masks", "distilled", "step").
    Returns the objects made (id, label, box), the masks' summary and the held-out figure
    of the fine-tune."""

def generate_shard(
    spec: Union[_Path, dict[str, Any]],
    out: _Path,
    shard: str = "0/1",
    seed: Optional[int] = None,
    count: Optional[int] = None,
    force: bool = False,
    coco_masks: str = "polygon",
    device: str = "cpu",
) -> dict[str, Any]:
    """Makes shard "i/n" of a run into the folder `out`, as `assist generate --shard i/n`
    does (a rerun remakes only what does not hold; a complete shard does nothing; "0/1"
    merges at its end); `device` is where the fields are queried. Returns the summary (made, skipped, seconds, record, …)."""

def merge(out: _Path, partial: bool = False, coco_masks: str = "polygon") -> dict[str, Any]:
    """Joins a run's samples into its COCO files and index.json, as `assist generate
    merge` does; refuses shards that do not hold, naming them."""

def status(out: _Path, shards: Optional[int] = None, hashes: bool = False) -> dict[str, Any]:
    """Which shards of the run in `out` are complete, partial, missing or another run's
    (`assist generate status --json`)."""
