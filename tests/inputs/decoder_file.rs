//! The full SpacetimeGaussians model's decoder file (`splats::decoder_json`): written weights
//! read back exactly, and every bad file refused naming the file, the field and the fix.

use lpmsplat::splats::decoder_json::{path_for, read_for, to_json, WEIGHTS};

#[test]
fn decoder_file_round_trips_and_refuses_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("adc+lpm.ply");
    assert_eq!(path_for(&ply), dir.path().join("adc+lpm.decoder.json"));
    let w: Vec<f32> = (0..WEIGHTS)
        .map(|k| (k as f32 * 0.37).sin() / 3.0)
        .collect();
    std::fs::write(path_for(&ply), to_json(&w).unwrap()).unwrap();
    assert_eq!(read_for(&ply).unwrap(), w, "exact round trip");
    assert!(to_json(&w[1..]).is_err(), "89 weights are not a decoder");

    let refused = |text: &str, field: &str| {
        std::fs::write(path_for(&ply), text).unwrap();
        let e = format!("{:#}", read_for(&ply).unwrap_err());
        assert!(
            e.contains("adc+lpm.decoder.json") && e.contains(field) && e.contains("Fix:"),
            "{e}"
        );
    };
    refused("{ not json", "not JSON");
    let mut doc: serde_json::Value = serde_json::from_str(&to_json(&w).unwrap()).unwrap();
    doc["w2"] = serde_json::json!([[1.0, 2.0]]);
    refused(&doc.to_string(), "'w2'");
    doc["w2"] = serde_json::Value::Null;
    refused(&doc.to_string(), "'w2'");
    let mut doc: serde_json::Value = serde_json::from_str(&to_json(&w).unwrap()).unwrap();
    doc["w1"][2][3] = serde_json::json!("x");
    refused(&doc.to_string(), "'w1'");
    std::fs::remove_file(path_for(&ply)).unwrap();
    let e = format!("{:#}", read_for(&ply).unwrap_err());
    assert!(
        e.contains("adc+lpm.decoder.json") && e.contains("Fix:"),
        "{e}"
    );
}
