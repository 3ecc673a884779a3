"""docs_examples.py, the helper the docs tests (fitting/, identification/) run a page's
worked example with: what it accepts and what it refuses, on small pages."""

from pathlib import Path

import pytest

from docs_examples import assert_prints_what_the_page_shows, block, shape

PAGE = """# A page

```toml
[fit]
```

Run:

```python
print("K = 0.4500 +- 0.0100{blank}")
print("done{tail}")
```

prints

```text
K = 0.45 +- 0.01
done
```

```text
a second block, not compared
```
"""


def _page(tmp_path: Path, blank: str = "", tail: str = "") -> Path:
    path = tmp_path / "page.md"
    path.write_text(PAGE.format(blank=blank, tail=tail))
    return path


def test_the_first_block_of_a_language() -> None:
    assert block(PAGE, "toml") == "[fit]\n"
    assert block(PAGE, "text") == "K = 0.45 +- 0.01\ndone\n"
    with pytest.raises(AssertionError, match="no ```json block"):
        block(PAGE, "json")


def test_shape() -> None:
    assert shape("x = -1.5e-3, n = 4 ") == ("x = #, n = # ", [-1.5e-3, 4.0])
    assert shape("x = 2 ", trailing_blanks=False) == ("x = #", [2.0])


def test_the_output_the_page_shows_passes(tmp_path: Path) -> None:
    assert_prints_what_the_page_shows(_page(tmp_path), tmp_path, timeout=60)


@pytest.mark.parametrize("tail", ['"); print("more', " 2", "!",
                                  '"); import sys; sys.exit(3); print("'],
                         ids=["a-line-more", "a-number-more", "another-text", "exit-3"])
def test_other_output_fails(tmp_path: Path, tail: str) -> None:
    with pytest.raises(AssertionError):
        assert_prints_what_the_page_shows(_page(tmp_path, tail=tail), tmp_path, timeout=60)


def test_a_number_off_by_more_than_1e_3_fails(tmp_path: Path) -> None:
    page = _page(tmp_path)
    page.write_text(page.read_text().replace("0.4500", "0.4506"))  # 1.3e-3 off
    with pytest.raises(AssertionError):
        assert_prints_what_the_page_shows(page, tmp_path, timeout=60)
    page.write_text(page.read_text().replace("0.4506", "0.4504"))  # 0.9e-3 off
    assert_prints_what_the_page_shows(page, tmp_path, timeout=60)


def test_trailing_blanks_count_unless_told(tmp_path: Path) -> None:
    page = _page(tmp_path, blank="  ")
    with pytest.raises(AssertionError):
        assert_prints_what_the_page_shows(page, tmp_path, timeout=60)
    assert_prints_what_the_page_shows(page, tmp_path, timeout=60, trailing_blanks=False)
