

def test_raw_pipe_with_a_wrong_size_or_pixel_format_is_said():
    """A wrong --size that still divides the stream, or gray bytes read as bgr24, runs but
    says so once; the right size says nothing (receiver.io.sources.likely_row_stride)."""
    import io as _io

    import numpy as np

    from receiver.cli.benchscene import bench_scene, render_bench_frame
    from receiver.io.sources import RawPipeSource, likely_row_stride

    img = render_bench_frame(bench_scene(), 0)  # 1280 x 720, 16 striped discs
    raw = img.tobytes()
    assert likely_row_stride(img.ravel(), 1280) is None
    assert likely_row_stride(img.ravel(), 1440) == 1280          # 1440 x 640 divides the stream
    assert likely_row_stride(img.ravel()[:426 * 3 * 720], 426 * 3) == 1280  # gray read as bgr24
    assert likely_row_stride(np.zeros(1280 * 720, np.uint8), 1440) is None  # a dark frame cannot tell

    def frames(size, fmt):
        return list(RawPipeSource(_io.BytesIO(raw * 2), size, fmt))

    import contextlib
    buf = _io.StringIO()
    with contextlib.redirect_stderr(buf):
        assert len(frames((1440, 640), "gray")) == 2
    assert buf.getvalue().count("wrong --size or --pix-fmt") == 1
    buf = _io.StringIO()
    with contextlib.redirect_stderr(buf):
        frames((1280, 720), "gray")
    assert "wrong --size" not in buf.getvalue()
