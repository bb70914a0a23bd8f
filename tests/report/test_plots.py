"""Drawing of the papers' figures: what a long trace keeps when it is drawn from its envelope."""
import numpy as np
import pytest


def test_trace_envelope_keeps_every_extreme_and_gap_in_bounded_points():
    """Long traces are drawn from their min-max envelope: at most the configured number of points, in time order,
    every bin's smallest and largest sample kept (a one-sample spike survives), a stretch without data stays a gap."""
    from selfsense.report.figures import FIGURE_TRACE_POINTS, _colour_runs, _envelope

    n = 250_001
    t = np.arange(n) * 1e-4
    y = np.sin(2 * np.pi * 0.3 * t)
    y[123_457] = 9.0            # a one-sample spike
    y[200_000:210_000] = np.nan  # no reference there
    te, ye = _envelope(t, y)
    assert len(te) <= FIGURE_TRACE_POINTS + 2 and np.all(np.diff(te) > 0)
    assert np.nanmax(ye) == 9.0 and np.nanmin(ye) == pytest.approx(np.nanmin(y), abs=1e-12)
    gap = (te >= t[200_500]) & (te <= t[209_500])
    assert gap.any() and np.isnan(ye[gap]).all()
    assert set(np.round(te / 1e-4).astype(int)) <= set(range(n))   # only samples of the trace, none invented
    short_t, short_y = _envelope(t[:100], y[:100])
    np.testing.assert_array_equal(short_y, y[:100])
    # the voltage-charge loop's polylines: one per colour of the map, starting where the colour changes
    import matplotlib.pyplot as plt

    norm = plt.Normalize(0.0, 10.0)
    tt = np.linspace(0.0, 10.0, 5001)
    starts = _colour_runs(norm, tt, 256)
    cmap = plt.get_cmap("viridis")
    colours = cmap(norm(tt))
    assert starts[0] == 0 and len(starts) == 256
    for a, b in zip(starts, np.append(starts[1:], len(tt))):
        assert np.all(colours[a:b] == colours[a])          # one colour per run
    assert not np.all(colours[starts[1:]] == colours[starts[1:] - 1], axis=1).any()   # a new colour at each start


def test_pdf_embeds_truetype_subsets_without_layout_tables_and_restores_the_loader(tmp_path):
    """The PDFs embed their fonts as TrueType subsets (``pdf.fonttype`` 42) with every glyph the text uses, without
    the OpenType layout tables a PDF viewer never reads; fontTools' loader is left as it was."""
    import io
    import re
    import zlib

    import matplotlib.pyplot as plt
    from fontTools import subset
    from fontTools.ttLib import TTFont

    from selfsense.report.figures import LAYOUT_TABLES, STYLE, _save

    loader = subset.load_font
    text = "tip force f_tip [mN] Δx_tip µC −1.5"
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(3, 2))
        ax.plot([-1.5, 2.0], [0.0, 1.0])
        ax.set_xlabel(text)
        ax.set_ylabel("charge q [µC]")
        _save(fig, tmp_path, "probe")
    assert subset.load_font is loader
    assert (tmp_path / "probe.png").stat().st_size > 0
    pdf = (tmp_path / "probe.pdf").read_bytes()
    assert b"/FontFile2" in pdf and b"/FontFile3" not in pdf and b"/Type3" not in pdf
    fonts = []
    for m in re.finditer(rb"/FontFile2 (\d+) 0 R", pdf):
        obj = re.search(rb"\n" + m.group(1) + rb" 0 obj\n<<(.*?)>>\nstream\n", pdf, re.DOTALL)
        n = int(re.search(rb"/Length (\d+)", obj.group(1)).group(1))
        fonts.append(TTFont(io.BytesIO(zlib.decompress(pdf[obj.end():obj.end() + n]))))
    assert fonts
    glyphs = set()
    for f in fonts:
        assert not set(LAYOUT_TABLES) & set(f.keys())
        assert {"glyf", "loca", "hmtx", "head", "cmap"} <= set(f.keys())
        glyphs |= set(f.getGlyphOrder())
    # the glyphs of the labels, the non-ASCII ones included (names of the font the figures use)
    from matplotlib import font_manager

    with plt.rc_context(STYLE):
        cmap = TTFont(font_manager.findfont(font_manager.FontProperties())).getBestCmap()
    assert {cmap[ord(c)] for c in text.replace(" ", "") + "q"} <= glyphs
