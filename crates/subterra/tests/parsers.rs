//! Seeded property tests of every TOML config parser (proptest): for any text, and for the
//! committed configs mutated the way files get damaged (cut, spliced, a value replaced by an
//! absurd one), parsing returns — it never panics — and an error is one line that says where.
//! What parses has passed its validation, so it can be built.

mod common;

use common::mutate::{apply, edit_strategy};
use proptest::prelude::*;
use subterra::plan::{MpcConfig, NavigatorConfig, RiskAStarConfig};
use subterra::{Config, PerceptionConfig, TerrainConfig};

fn committed(name: &str) -> String {
    let path = format!("{}/../../configs/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// A check that parses `text`: `Err` holds the parser's message.
type Parse = fn(&str) -> Result<(), String>;

/// Every parser: its name, the committed file it reads, and a check that parses `text`.
fn parsers() -> Vec<(&'static str, String, Parse)> {
    fn run<T>(r: subterra::Result<T>) -> Result<(), String> {
        r.map(|_| ()).map_err(|e| e.to_string())
    }
    vec![
        ("flight", committed("flight"), |t| run(PerceptionConfig::from_toml_str(t))),
        ("terrain", committed("terrain"), |t| run(TerrainConfig::from_toml_str(t))),
        ("astar", committed("astar"), |t| run(RiskAStarConfig::from_toml_str(t))),
        ("mpc", committed("mpc"), |t| run(MpcConfig::from_toml_str(t))),
        ("navigator", committed("navigator"), |t| run(NavigatorConfig::from_toml_str(t))),
    ]
}

fn check(name: &str, parse: Parse, text: &str) -> Result<(), TestCaseError> {
    if let Err(message) = parse(text) {
        prop_assert!(!message.contains('\n'), "{name}: a multi-line error for {text:?}: {message}");
        prop_assert!(!message.is_empty(), "{name}: an empty error");
        prop_assert!(message.len() < 2000, "{name}: a {}-byte error", message.len());
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, rng_seed: proptest::test_runner::RngSeed::Fixed(22), ..ProptestConfig::default() })]

    #[test]
    fn damaged_configs_parse_or_give_a_one_line_error(edits in prop::collection::vec(edit_strategy(), 1..4)) {
        for (name, text, parse) in parsers() {
            let damaged = edits.iter().fold(text.clone(), |t, e| apply(&t, e));
            check(name, parse, &damaged)?;
        }
    }

    #[test]
    fn any_text_parses_or_gives_a_one_line_error(text in "\\PC{0,300}") {
        for (name, _, parse) in parsers() {
            check(name, parse, &text)?;
        }
    }
}

#[test]
fn the_committed_configs_parse() {
    for (name, text, parse) in parsers() {
        parse(&text).unwrap_or_else(|e| panic!("configs/{name}.toml: {e}"));
    }
}

#[test]
fn a_bad_value_is_named_by_its_field_and_line() {
    let text = committed("flight").replace("particles = 20000", "particles = -5");
    let err = PerceptionConfig::from_toml_str(&text).unwrap_err().to_string();
    assert!(err.contains("filter.particles (line ") && err.contains("expected usize"), "{err}");
    let err = PerceptionConfig::from_toml_str(&committed("flight").replace("particles = 20000", "particles = nan")).unwrap_err().to_string();
    assert!(err.contains("filter.particles"), "{err}");
    let err = TerrainConfig::from_toml_str("[coarse]\nresolution_m = \"fine\"\n").unwrap_err().to_string();
    assert!(err.contains("coarse.resolution_m (line 2, column 16)"), "{err}");
    // Nesting is bounded by the parser: an error, not a stack overflow.
    let deep = format!("a = {}{}", "[".repeat(100_000), "]".repeat(100_000));
    assert!(PerceptionConfig::from_toml_str(&deep).unwrap_err().to_string().contains("recurs"));
}
