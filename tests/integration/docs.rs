//! The measured pages say what they measured, and fail the build when that is no longer the
//! code: `docs/results.md` names the file format version its figures were measured on (written
//! by `tools/results.py` from `oavm-bench --json`), and a page measured on another format is
//! stale (format 4 changed what OAVM's solid leaves are, and its speed with them).

use oavm::physical::format::VERSION;

/// The format version a generated page names (`file format version N`), if it names one.
fn named_version(page: &str) -> Option<u32> {
    let at = page.find("file format version ")? + "file format version ".len();
    let digits: String = page[at..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().ok()
}

#[test]
fn results_page_was_measured_on_this_format_version() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/results.md");
    let page = std::fs::read_to_string(path).expect("docs/results.md");
    let named = named_version(&page).expect(
        "docs/results.md names no `file format version`: regenerate it with tools/results.sh",
    );
    assert_eq!(
        named, VERSION,
        "docs/results.md was measured on file format version {named}, the code writes version \
         {VERSION}: run tools/results.sh again"
    );
    assert!(
        page.contains("Measured at commit `"),
        "docs/results.md names no commit"
    );
}

#[test]
fn a_page_without_a_version_or_with_another_is_told_apart() {
    assert_eq!(
        named_version("measured at file format version 3, and"),
        Some(3)
    );
    assert_eq!(named_version("no version here"), None);
    assert_eq!(named_version("file format version x"), None);
}
