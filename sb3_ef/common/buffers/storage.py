"""Where a sequence buffer's data lives: torch tensors in host memory (optionally memory-mapped) or on a GPU."""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings

import numpy as np
import torch as th

# "auto" keeps this share of the GPU's total memory (at least MIN_DEVICE_MARGIN) free for the model and the update.
DEVICE_MARGIN_FRACTION = 0.25
MIN_DEVICE_MARGIN = 4 * 2**30


def available_host_memory() -> int | None:
    """Bytes of RAM the kernel reports as available (``MemAvailable``), or None where it does not say."""
    try:
        import psutil  # optional, as in SB3

        return int(psutil.virtual_memory().available)
    except ImportError:
        pass
    try:
        with open("/proc/meminfo") as meminfo:
            return next(int(line.split()[1]) * 1024 for line in meminfo if line.startswith("MemAvailable:"))
    except (OSError, StopIteration):
        return None


def storage_request(storage_device: str | th.device) -> str | th.device:
    """``"auto"`` or a torch device, refused when it needs CUDA this machine lacks."""
    if storage_device == "auto":
        return "auto"
    try:
        device = th.device(storage_device)
    except (RuntimeError, TypeError) as error:
        raise ValueError(
            "SequenceReplayBuffer expects storage_device 'auto', 'cpu', 'cuda' or a torch.device, "
            f"got {storage_device!r}"
        ) from error
    if device.type == "cuda" and not th.cuda.is_available():
        raise ValueError(f"SequenceReplayBuffer storage_device={storage_device!r} needs CUDA, which is not available")
    return device


def normalize_device(device: th.device | str) -> th.device:
    """``cuda`` with its index filled in, so that devices compare equal to their tensors' ``.device``."""
    device = th.device(device)
    if device.type == "cuda" and device.index is None:
        return th.device("cuda", th.cuda.current_device())
    return device


def zeros(shape: tuple[int, ...], dtype: th.dtype, device: th.device) -> th.Tensor:
    """Zeros on ``device``; in host memory through ``np.zeros`` (calloc), whose pages the OS commits when written."""
    if device.type != "cpu":
        return th.zeros(shape, dtype=dtype, device=device)
    numpy_dtype = th.empty(0, dtype=dtype).numpy().dtype
    return th.from_numpy(np.zeros(shape, dtype=numpy_dtype))


def write_rows(target: th.Tensor, rows: list[int] | np.ndarray, values: np.ndarray) -> None:
    """``target[rows] = values`` on the target's device (through pinned memory, without blocking, on a CUDA GPU)."""
    source, index = th.from_numpy(np.ascontiguousarray(values)), th.as_tensor(np.asarray(rows, dtype=np.int64))
    if target.device.type != "cpu":
        cuda = target.device.type == "cuda"
        source = (source.pin_memory() if cuda else source).to(target.device, non_blocking=cuda)
        index = (index.pin_memory() if cuda else index).to(target.device, non_blocking=cuda)
    target.index_copy_(0, index, source)


class FrameStorage:
    """The buffer's tensors, allocated on demand; row ``e * capacity + s`` is slot ``s`` of env ``e``, the last zero."""

    STEP_TENSORS = ("actions", "rewards", "dones", "timeouts")

    def __init__(
        self,
        rows: int,
        frame_shape: tuple[int, ...],
        action_dim: int,
        mask_bytes: int | None,
        memmap_dir: str | None,
        frame_stack: int,
    ) -> None:
        self.rows, self.frame_shape, self.action_dim = rows, frame_shape, action_dim
        self.mask_bytes, self.memmap_dir, self.frame_stack = mask_bytes, memmap_dir, frame_stack
        self.allocated = False  # the tensors below exist (allocated at the first add(), or when a pickle is loaded)
        self.frame_map: np.memmap | None = None
        self.frames = self.actions = self.rewards = self.dones = self.timeouts = self.step_flags = th.empty(0)
        self.masks: th.Tensor | None = None

    @property
    def device(self) -> th.device:
        return self.frames.device

    def bytes_needed(self) -> tuple[int, int]:
        """Bytes of the frames and of everything else (step arrays, step flags, masks) with the zero row."""
        rows = self.rows + 1
        step = 4 * self.action_dim + 4 + 1 + 1 + 1 + (self.mask_bytes or 0)
        return rows * int(np.prod(self.frame_shape)), rows * step

    def choose_device(self, request: str | th.device, training: th.device) -> th.device:
        """The device ``request`` names here: ``"auto"`` is the training GPU when everything plus a margin fits."""
        if isinstance(request, th.device):
            if request.type == "cuda" and not th.cuda.is_available():  # a buffer loaded on a machine without CUDA
                warnings.warn(f"SequenceReplayBuffer storage_device={request} needs CUDA: frames stay in host memory")
                return th.device("cpu")
            return normalize_device(request)
        training = normalize_device(training)
        if self.memmap_dir is None and training.type == "cuda":
            free, total = th.cuda.mem_get_info(training)
            if sum(self.bytes_needed()) + max(MIN_DEVICE_MARGIN, DEVICE_MARGIN_FRACTION * total) <= free:
                return training
        return th.device("cpu")

    def check_memory(self, device: th.device) -> None:
        """Raise before allocating when ``device`` cannot hold the storage, naming the ways out."""
        frame_bytes, step_bytes = self.bytes_needed()
        available: int | None
        ways_out = [
            f"a smaller buffer_size (an episode of T steps takes T + {self.frame_stack} frames; to go on training a "
            "saved model, Model.load(path, buffer_size=...))"
        ]
        if device.type == "cuda":
            needed, available, where = frame_bytes + step_bytes, th.cuda.mem_get_info(device)[0], f"{device} memory"
            ways_out.append("storage_device='cpu' (host memory; batches are copied to the GPU)")
        elif self.memmap_dir is not None:
            os.makedirs(self.memmap_dir, exist_ok=True)
            needed, available = frame_bytes, shutil.disk_usage(self.memmap_dir).free
            where = f"disk space in memmap_dir={self.memmap_dir}"
            ways_out.append("a memmap_dir on a larger disk")
        else:
            needed, available, where = frame_bytes + step_bytes, available_host_memory(), "RAM"
            ways_out.append(
                f"memmap_dir=<a folder on a disk with {frame_bytes / 1e9:.1f} GB free> (frames in a file, read "
                "through the page cache)"
            )
        if available is None or needed <= available:
            return
        raise MemoryError(
            f"SequenceReplayBuffer needs {needed / 1e9:.2f} GB ({self.rows} frames of {self.frame_shape} uint8 and "
            f"their step data) but only {available / 1e9:.2f} GB of {where} are available. "
            f"Ways out: {'; or '.join(ways_out)}."
        )

    def allocate(self, device: th.device, step_flags: np.ndarray) -> None:
        """Zeroed tensors (frames in RAM, in an unnamed temporary file under ``memmap_dir``, or on a GPU)."""
        self.check_memory(device)
        rows = self.rows + 1
        self.frame_map = None
        if self.memmap_dir is not None:
            # The file has no name and the mapping keeps it alive: it is freed with the array, even after a crash.
            with tempfile.TemporaryFile(dir=self.memmap_dir, prefix="sb3_ef_frames_") as file:
                self.frame_map = np.memmap(file, dtype=np.uint8, mode="w+", shape=(rows, *self.frame_shape))
            self.frames = th.from_numpy(self.frame_map)
        else:
            self.frames = zeros((rows, *self.frame_shape), th.uint8, device)
        self.actions = zeros((rows, self.action_dim), th.float32, device)
        self.rewards = zeros((rows,), th.float32, device)
        self.dones = zeros((rows,), th.bool, device)
        self.timeouts = zeros((rows,), th.bool, device)
        self.masks = None if self.mask_bytes is None else zeros((rows, self.mask_bytes), th.uint8, device)
        self.allocated = True
        self.share_step_flags(step_flags)

    def move(self, device: th.device, step_flags: np.ndarray) -> None:
        self.check_memory(device)
        for name in ("frames", *self.STEP_TENSORS):
            setattr(self, name, getattr(self, name).to(device))
        if self.masks is not None:
            self.masks = self.masks.to(device)
        self.share_step_flags(step_flags)

    def share_step_flags(self, step_flags: np.ndarray) -> None:
        """Step flags on the storage device: the host array itself in host memory, a copy on a GPU."""
        flags = th.from_numpy(step_flags)
        self.step_flags = flags if self.device.type == "cpu" else flags.to(self.device)

    def write_frames(self, rows: list[int], frames: np.ndarray, masks: np.ndarray | None) -> None:
        write_rows(self.frames, rows, frames)
        if masks is not None:
            assert self.masks is not None, "masks are written only where they are stored"
            write_rows(self.masks, rows, masks)

    def write_steps(self, rows: np.ndarray, **values: np.ndarray) -> None:
        for name, value in values.items():
            write_rows(getattr(self, name), rows, value)

    def update_step_flags(self, rows: np.ndarray, step_flags: np.ndarray) -> None:
        """Copy the host's step flags of ``rows`` to a GPU storage (host storage shares the host array)."""
        if self.device.type != "cpu":
            write_rows(self.step_flags, rows, step_flags[rows])
