"""Write the substitute background videos of this study in the DAVIS layout (one folder of JPEG frames per video).

DAVIS 2017 cannot be downloaded on the machine this study ran on, so the dynamic background is made from four
colour photographs that ship with scikit-image (``astronaut``, ``chelsea``, ``coffee``, ``rocket``; public domain
or CC0, see skimage.data): each video is a window that pans and zooms across one photograph while a disc cut from a
fifth photograph (``hubble_deep_field``) crosses it on a bouncing path. Like a DAVIS video, every frame differs
from the last, both in the whole texture (camera motion) and in one moving object; unlike DAVIS, the motion is
smooth and periodic. Pass the folder as ``background_dir`` with ``background_videos=list(VIDEOS)``.

    pip install scikit-image
    python experiments/2026-12-distracting-cpu/make_backgrounds.py experiments/2026-12-distracting-cpu/backgrounds
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

#: The videos, named after the photograph each pans over (the first four: the "easy" difficulty's count).
VIDEOS: tuple[str, ...] = ("astronaut", "chelsea", "coffee", "rocket")


def video_frames(photo: np.ndarray, sprite: np.ndarray, frames: int, size: int, phase: float) -> list[np.ndarray]:
    """``frames`` RGB frames of ``size`` x ``size``: a panning, zooming window over ``photo`` with ``sprite``
    (a disc) moving across it."""
    height, width = photo.shape[:2]
    radius = sprite.shape[0] // 2
    yy, xx = np.mgrid[-radius:radius, -radius:radius]
    disc = (yy**2 + xx**2) < radius**2
    out = []
    for index in range(frames):
        t = 2 * np.pi * index / frames
        side = int(min(height, width) * (0.55 + 0.15 * np.sin(t + phase)))
        top = int((height - side) * (0.5 + 0.5 * np.sin(t)))
        left = int((width - side) * (0.5 + 0.5 * np.cos(2 * t + phase)))
        window = Image.fromarray(photo[top : top + side, left : left + side])
        frame = np.array(window.resize((size, size), Image.Resampling.BILINEAR))
        centre_y = int((size - 2 * radius) * abs(np.sin(1.5 * t + phase))) + radius
        centre_x = int((size - 2 * radius) * index / max(1, frames - 1)) + radius
        patch = frame[centre_y - radius : centre_y + radius, centre_x - radius : centre_x + radius]
        patch[disc] = sprite[disc]
        out.append(frame)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", help="folder to write (it gets one sub-folder per video)")
    parser.add_argument("--frames", type=int, default=80, help="frames per video (DAVIS videos have 50-104)")
    parser.add_argument("--size", type=int, default=160, help="frame side in pixels")
    args = parser.parse_args()
    import skimage.data

    sprite_side = args.size // 4
    sprite = np.array(Image.fromarray(skimage.data.hubble_deep_field()[:400, :400]).resize((sprite_side, sprite_side)))
    for number, name in enumerate(VIDEOS):
        folder = Path(args.out) / name
        folder.mkdir(parents=True, exist_ok=True)
        photo = getattr(skimage.data, name)()
        for index, frame in enumerate(video_frames(photo, sprite, args.frames, args.size, phase=number)):
            Image.fromarray(frame).save(folder / f"{index:05d}.jpg", quality=90)
        print(f"{folder}: {args.frames} frames")


if __name__ == "__main__":
    main()
