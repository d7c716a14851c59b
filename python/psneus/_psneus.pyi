"""Type stubs of the extension module ``psneus._psneus`` (written by hand; ``python/src``)."""

from os import PathLike
from typing import Any, Callable, Optional, Sequence, TypedDict, Union

import numpy as np
import numpy.typing as npt

__version__: str

_Path = Union[str, "PathLike[str]"]

class Camera(TypedDict):
    K: npt.NDArray[np.float64]  # (3, 3), pixel centres at integer coordinates
    world_from_camera: npt.NDArray[np.float64]  # (4, 4), normalised frame, OpenCV axes
    width: int
    height: int
    name: str

class Scene:
    """A calibrated multi-view scene in the normalised frame (region of interest = unit sphere)."""

    @property
    def cameras(self) -> list[Camera]: ...
    @property
    def world_from_normalized(self) -> npt.NDArray[np.float64]:
        """(4, 4): the normalised frame → the dataset's world (e.g. DTU's scale_mat)."""
    @property
    def description(self) -> str: ...
    @property
    def path(self) -> Optional[str]: ...
    def image(self, i: int) -> npt.NDArray[np.float32]:
        """View i's image, (height, width, 3) float32 in [0, 1]."""
    def mask(self, i: int) -> Optional[npt.NDArray[np.bool_]]:
        """View i's foreground mask, (height, width) bool, or None."""
    def ground_truth(self, spacing: float = 0.004) -> Optional[npt.NDArray[np.float32]]:
        """Ground-truth surface points, (N, 3) float32 in the normalised frame, or None."""
    def __len__(self) -> int: ...

def load_scene(path: Optional[_Path] = None, **options: Any) -> Scene:
    """A dataset folder in any layout the loaders read, or None for the built-in golden scene.

    options: the ``data.*`` keys (``downscale``, ``bound=[x, y, z, r]``,
    ``builtin={"shape": "composite", "width": 200, "views": 49, "backdrop": True}``).
    Raises OSError (a file missing or unreadable) or ValueError (bad content), naming the file.
    """

class UpdateReport(TypedDict):
    seconds: float
    s: float
    field_queries: int
    scene_mass: float
    occupied_fraction: float
    empty_views: list[int]  # estimator cameras whose grid holds no mass (drawn uniformly)
    lipschitz_measured: float
    lipschitz_claimed: float
    lipschitz_used: float
    lipschitz_retries: int

class Rays(TypedDict, total=False):
    view: npt.NDArray[np.int64]  # (n,) scene view index
    pixel: npt.NDArray[np.float64]  # (n, 2) x, y of the colour target's centre (integer = centre)
    pixel_coords: npt.NDArray[np.float64]  # (n, 2) the continuous position drawn, same convention
    origin: npt.NDArray[np.float32]  # (n, 3) normalised frame
    direction: npt.NDArray[np.float32]  # (n, 3) unit, through `pixel`
    depth: npt.NDArray[np.float32]  # (n,) the guided sample λ̃ as a distance along direction; NaN without
    depth_bin: npt.NDArray[np.float32]  # (n,) one depth bin of the guide along the ray: λ̃'s resolution
    background: npt.NDArray[np.bool_]  # (n,) no λ̃ from the guide, or λ̃ outside the unit sphere
    guided: npt.NDArray[np.bool_]  # (n,) False for the uniform share
    pdf: npt.NDArray[np.float32]  # (n,) the pixel's density under the guide, per pixel²
    near: npt.NDArray[np.float32]  # (n,) NeuS's near and far in the unit sphere
    far: npt.NDArray[np.float32]
    coarse_depths: npt.NDArray[np.float32]  # (n, coarse + 1) with coarse > 0

class EstimatorState(TypedDict):
    grids: list[npt.NDArray[np.float32]]
    occupancy: Optional[npt.NDArray[np.float32]]
    part: Optional[int]
    lipschitz: float

Sdf = Union[Callable[[npt.NDArray[np.float32]], Any], "Sphere"]
"""(N, 3) float32 points of the normalised frame → (N,) signed distances (anything numpy.asarray
takes: a numpy array, a CPU torch tensor without grad)."""

class Sphere:
    """An analytic sphere: evaluated in Rust by Estimator.update and extract_mesh, callable here."""

    def __init__(self, center: Sequence[float], radius: float) -> None: ...
    def __call__(self, points: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]: ...

class Estimator:
    """The probability-guided estimator over views of a scene, for any backbone."""

    def __init__(
        self,
        scene: Scene,
        views: Optional[Sequence[int]] = None,
        sampler: str = "guided",
        skip_empty: Optional[bool] = None,
        occupancy_dilation: Optional[int] = None,
        **guide: Any,
    ) -> None:
        """guide: the ``guide.*`` keys (``updates``, ``scene={...}``, ``camera={...}``,
        ``interpolation``, ``fixed_s``, ``uniform_fractions``; ``scene__resolution=64``)."""
    def update(self, sdf: Sdf, s: float, progress: float = 0.0) -> UpdateReport:
        """Rebuild the guide from sdf at logistic scale s (called in batches, GIL taken per batch)."""
    def update_due(self, progress: float, sdf: Sdf, s: float) -> Optional[UpdateReport]:
        """The scheduled update (``updates`` per run), or None when none is due."""
    def draw(
        self,
        n: int,
        seed: int,
        uniform_fraction: Optional[float] = None,
        progress: float = 0.0,
        step: int = 0,
        coarse: int = 0,
    ) -> Rays:
        """n rays, deterministic for (seed, step); the schedule's uniform share at progress unless
        uniform_fraction is given."""
    def state(self) -> EstimatorState: ...
    def restore(self, state: EstimatorState) -> None: ...
    @property
    def views(self) -> list[int]: ...
    @property
    def lipschitz_bound(self) -> float: ...
    def uniform_fraction(self, progress: float) -> float: ...

def train(
    data: Optional[_Path] = None,
    budget: Union[str, float, None] = None,
    out: Optional[_Path] = None,
    sampler: Optional[str] = None,
    seed: Optional[int] = None,
    config: Optional[_Path] = None,
    resume: Optional[_Path] = None,
    overwrite: bool = False,
    max_memory_gb: Optional[float] = None,
    **overrides: Any,
) -> dict[str, Any]:
    """Train (``cargo xtask train``); returns metrics.json's fields with ``mesh``, ``meshes``, ``out``.

    budget: "2m", "90s", "1.5h" or seconds (None: the configuration's, 2 minutes; ``steps=N``
    trains N iterations). sampler: "guided" (default), "uniform", "error-map" or "soft-mining".
    overrides: configuration keys (``**{"data.masks": False}`` or
    ``data__masks=False``). Ctrl-C writes a checkpoint and raises KeyboardInterrupt;
    ``train(resume=out)`` continues.
    """

def evaluate_mesh(
    mesh: Union[_Path, tuple[npt.ArrayLike, npt.ArrayLike]],
    gt_points: Optional[npt.ArrayLike] = None,
    gt_mesh: Union[_Path, tuple[npt.ArrayLike, npt.ArrayLike], None] = None,
    spacing: Optional[float] = None,
    max_dist: Optional[float] = None,
    tau: Optional[float] = None,
) -> dict[str, Optional[float]]:
    """DTU-protocol accuracy, completeness, chamfer, precision, recall, fscore in the mesh's units;
    normal_consistency: the mean |n · n'| of the mesh's and the truth mesh's normals over the same
    pairs (None against ``gt_points``, or when no pair lies within ``max_dist``)."""

def extract_mesh(
    sdf: Sdf, resolution: int = 128, bound: float = 1.0, lipschitz: float = 1.5
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]]:
    """Marching cubes of sdf's zero level set over [-bound, bound]³: (vertices, faces)."""

def default_config() -> str:
    """Every configuration key with its default and description, as TOML."""
