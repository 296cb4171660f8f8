"""What a view's "save" buttons send to the browser that clicked them: the page's 3D view as a
PNG (rendered by that browser at the size asked) and the view's data as CSV."""

from __future__ import annotations

import io

import numpy as np

__all__ = ["csv_bytes", "png_bytes", "save_render"]

#: the size of a saved picture [px] (height, width)
RENDER_SIZE = (800, 1280)


def png_bytes(img: np.ndarray) -> bytes:
    """An RGB(A) image (H, W, 3 or 4) of uint8 as PNG bytes."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.asarray(img, np.uint8)).save(out, format="PNG")
    return out.getvalue()


def csv_bytes(header: list[str], columns: list[np.ndarray], digits: int = 9) -> bytes:
    """Columns of equal length as CSV with a header line (``%.{digits}g`` numbers)."""
    rows = np.column_stack([np.asarray(c, float) for c in columns])
    text = io.StringIO()
    text.write(",".join(header) + "\n")
    np.savetxt(text, rows, delimiter=",", fmt=f"%.{digits}g")
    return text.getvalue().encode()


def save_render(client, filename: str = "trackflow_view.png") -> None:
    """Ask ``client`` (a viser client, the one that clicked) to render its view and send it
    back to it as a PNG download."""
    img = np.asarray(client.get_render(*RENDER_SIZE, transport_format="png"))
    if img.shape[-1] == 4:  # the canvas is transparent where nothing is drawn: the page's white
        a = img[..., 3:4].astype(float) / 255.0
        img = np.rint(img[..., :3] * a + 255.0 * (1.0 - a)).astype(np.uint8)
    client.send_file_download(filename, png_bytes(img), save_immediately=True)
