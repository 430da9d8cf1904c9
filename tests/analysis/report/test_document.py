"""The report's document model: HTML escaping and figure links."""

from __future__ import annotations

from rmi_learn.analysis.report import Doc


def test_doc_escapes_html() -> None:
    d = Doc()
    d.h(1, "t")
    d.p("a <b> & `x<y`")
    d.table(["h"], [["<i>"]])
    page = d.html("t")
    assert "a &lt;b&gt; &amp; <code>x&lt;y</code>" in page and "<td>&lt;i&gt;</td>" in page


def test_doc_links_figures_when_not_embedding() -> None:
    d = Doc()
    d.h(1, "t")
    d.img("figures/a.png", "a")
    assert '<img src="figures/a.png"' in d.html("t")
