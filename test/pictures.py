"""Reading the pictures of core/report as a user looks at them: the panels of a report (their
frames), the panels of refine's contact sheet (their label bars), the error map (its colours
read back through the colour bar's colour map)."""
import cv2
import numpy as np

from zeroshot_calib_ros.core.report import calibration_report, canvas, debug_sheet


def report_panels(image):
    """{column index: [(x, y, w, h) of each panel's frame, top to bottom]} of a report: the
    rectangles framed in the panel edge colour, found along the left edge of each column."""
    width = calibration_report.WIDTH
    assert image.shape[1] == width, image.shape
    panel_w = (width - 2 * calibration_report.MARGIN - 2 * calibration_report.GAP) // 3
    edge = np.all(image == canvas.PANEL_EDGE, axis=2)
    found = {}
    for column in range(3):
        x = calibration_report.MARGIN + column * (panel_w + calibration_report.GAP)
        runs, start = [], None
        for y, on in enumerate(list(edge[:, x]) + [False]):
            if on and start is None:
                start = y
            elif not on and start is not None:
                if y - start > 100:
                    runs.append((x, start, panel_w, y - start))
                start = None
        found[column] = runs
    return found


def region(image, rect, inset=4):
    x, y, w, h = rect
    return image[y + inset:y + h - inset, x + inset:x + w - inset]


def is_drawn_on(picture_region, min_fraction=0.03):
    """Something is drawn in the region: enough pixels far from white and some contrast."""
    grey = cv2.cvtColor(picture_region, cv2.COLOR_BGR2GRAY)
    return float(np.mean(grey < 200)) > min_fraction and float(grey.std()) > 10


def colormap_indices(picture_region):
    """(mask, index): the pixels whose colour is one of the colour map's 256 (the error map and
    the colour bar), and for them that colour's place on the bar (0: bottom, 255: top)."""
    lut = canvas.colour_lut().astype(np.int32)
    codes = {int(b) << 16 | int(g) << 8 | int(r): k for k, (b, g, r) in enumerate(lut)}
    p = picture_region.astype(np.int32)
    packed = p[..., 0] << 16 | p[..., 1] << 8 | p[..., 2]
    index = np.full(packed.shape, -1)
    for code, k in codes.items():
        index[packed == code] = k
    return index >= 0, index


def error_map(image, rect):
    """(index image, (x, y, w, h)) of the error map in the panel ``rect``: the largest connected
    area of colour-map colours (the colour bar beside it is narrower)."""
    mask, index = colormap_indices(region(image, rect, 0))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=4)
    assert count > 1, 'no colour-map colours in the panel'
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h = stats[best, :4]
    return index[y:y + h, x:x + w], (x, y, w, h)


def sheet_panels(image, aspect):
    """[(x, y, w, h) of each panel's image, below its label bar], in reading order, of a contact
    sheet of images of ``aspect`` (height / width): the label bars are the areas of exactly the
    label colour, one per panel."""
    bar = np.all(image == debug_sheet.LABEL_BG, axis=2).astype(np.uint8)
    count, _, stats, _ = cv2.connectedComponentsWithStats(bar, connectivity=4)
    panels = []
    for x, y, w, h, area in stats[1:]:
        if abs(h - debug_sheet.LABEL_H) <= 1 and w >= 40 and area > 0.5 * w * h:
            panels.append((int(x), int(y + h), int(w), int(round(w * aspect))))
    panels.sort(key=lambda p: (p[1], p[0]))
    return panels


def correlation(a, b):
    a = a.astype(float).ravel() - a.mean()
    b = b.astype(float).ravel() - b.mean()
    return float(a @ b / np.sqrt((a @ a) * (b @ b) + 1e-12))


def shows(picture_region, image):
    """Normalised correlation of a panel's picture with ``image`` scaled to it (grey)."""
    grey = cv2.cvtColor(picture_region, cv2.COLOR_BGR2GRAY)
    source = image if image.ndim == 2 else cv2.cvtColor(image[..., :3], cv2.COLOR_BGR2GRAY)
    small = cv2.resize(source, (grey.shape[1], grey.shape[0]), interpolation=cv2.INTER_AREA)
    return correlation(grey, small)
