//! Helpers shared by the integration tests.

/// A folder of `../shared/data` that a test needs is missing (`what` names it). With
/// `SVGIR_REQUIRE_DATA=1` (set by `.ci/run`) the test fails; otherwise it prints `SKIPPED` and
/// the caller returns.
pub fn missing_data(what: &str) {
    let msg = format!("{what} not found; this test needs ../shared/data");
    if std::env::var("SVGIR_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!("SVGIR_REQUIRE_DATA=1: {msg}");
    }
    eprintln!("SKIPPED: {msg}");
}
