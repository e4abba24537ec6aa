"""Reading the package's map pictures back: a figure rendered to RGB, and the pixel under a
point of its axes (tests of `plot_flip_map` and `plot_indicator_map`)."""
import numpy as np


def render(fig):
    """The figure drawn by Agg, as RGB floats in [0, 1] (rows from the top)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].astype(float) / 255


def pixel(fig, rgb, x_deg, y_deg):
    """The colour in `rgb` (from `render`) at data point (x_deg, y_deg) of the first axes."""
    px, py = fig.axes[0].transData.transform((x_deg, y_deg))
    return rgb[int(round(rgb.shape[0] - py)), int(round(px))]
