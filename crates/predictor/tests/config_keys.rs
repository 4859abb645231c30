//! A weights file whose model config repeats a key is refused naming the key (serde_json would
//! keep the last value silently), even when its content hash was stamped over the edited
//! config.
#![allow(clippy::unwrap_used)]

use nudge_predictor::weights::{ModelConfig, restamp, synthetic_weights};
use nudge_predictor::{ModelWeights, PredictorError};
use safetensors::SafeTensors;

/// `bytes` with the `config` metadata string replaced by `edit(config)`, re-stamped.
fn with_config(bytes: &[u8], edit: impl Fn(&str) -> String) -> Vec<u8> {
    let st = SafeTensors::deserialize(bytes).unwrap();
    let (_, header) = SafeTensors::read_metadata(bytes).unwrap();
    let mut meta = header.metadata().clone().unwrap();
    let config = edit(&meta["config"]);
    meta.insert("config".to_owned(), config);
    restamp(&safetensors::serialize(st.tensors(), Some(meta)).unwrap()).unwrap()
}

#[test]
fn repeated_keys_in_the_model_config_are_refused_naming_the_key() {
    let bytes = synthetic_weights(&ModelConfig::student(), 3).unwrap();
    // Sanity: the untouched and a re-serialised config load.
    ModelWeights::from_bytes(&bytes).unwrap();
    ModelWeights::from_bytes(&with_config(&bytes, str::to_owned)).unwrap();
    // "t_plan" repeated (same value, then another one): both refused.
    for extra in [r#""t_plan": 6, "#, r#""t_plan": 7, "#] {
        let dup = with_config(&bytes, |c| c.replacen('{', &format!("{{{extra}"), 1));
        match ModelWeights::from_bytes(&dup) {
            Err(e @ PredictorError::BadConfig { .. }) => {
                let msg = e.to_string();
                assert!(msg.contains("duplicate key `t_plan`"), "{msg}");
            }
            other => panic!(
                "{extra}: expected BadConfig, got {:?}",
                other.map(|_| "weights")
            ),
        }
    }
}
