//! Every malformed weights file and every malformed input gets its own typed error, never a
//! panic. Malformed files are built here by rewriting a valid one with `safetensors`.
#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::path::PathBuf;

use nudge_predictor::weights::synthetic_weights;
use nudge_predictor::{
    ConstantVelocity, History, MAX_AGENTS, ModelConfig, ModelWeights, Predictor, PredictorError,
    Student, T_OBS, Teacher, load_predictor,
};
use safetensors::tensor::TensorView;
use safetensors::{Dtype, SafeTensors};

/// A weights file taken apart: tensors `(name, dtype, shape, bytes)` and metadata.
struct Parts {
    tensors: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
    meta: HashMap<String, String>,
}

impl Parts {
    fn of(bytes: &[u8]) -> Self {
        let st = SafeTensors::deserialize(bytes).unwrap();
        let (_, header) = SafeTensors::read_metadata(bytes).unwrap();
        let tensors = st
            .tensors()
            .into_iter()
            .map(|(n, v)| (n, v.dtype(), v.shape().to_vec(), v.data().to_vec()))
            .collect();
        Self {
            tensors,
            meta: header.metadata().clone().unwrap_or_default(),
        }
    }

    fn teacher() -> Self {
        Self::of(&synthetic_weights(&ModelConfig::teacher(), 11).unwrap())
    }

    fn student() -> Self {
        Self::of(&synthetic_weights(&ModelConfig::student(), 12).unwrap())
    }

    fn bytes(&self) -> Vec<u8> {
        let views: Vec<(String, TensorView<'_>)> = self
            .tensors
            .iter()
            .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).unwrap()))
            .collect();
        safetensors::serialize(views, Some(self.meta.clone())).unwrap()
    }

    fn tensor_mut(&mut self, name: &str) -> &mut (String, Dtype, Vec<usize>, Vec<u8>) {
        self.tensors.iter_mut().find(|t| t.0 == name).unwrap()
    }

    fn config(&self) -> serde_json::Value {
        serde_json::from_str(&self.meta["config"]).unwrap()
    }

    fn set_config(&mut self, v: &serde_json::Value) {
        self.meta.insert("config".into(), v.to_string());
    }

    fn load(&self) -> Result<ModelWeights, PredictorError> {
        ModelWeights::from_bytes(&self.bytes())
    }
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

#[test]
fn valid_files_load() {
    assert!(Parts::teacher().load().is_ok());
    assert!(Parts::student().load().is_ok());
    assert!(Teacher::from_bytes(&Parts::teacher().bytes()).is_ok());
    assert!(Student::from_bytes(&Parts::student().bytes()).is_ok());
}

#[test]
fn missing_tensor() {
    for mut p in [Parts::teacher(), Parts::student()] {
        p.tensors
            .retain(|t| t.0 != "pool_net.mlp_pre_pool.2.weight");
        match p.load() {
            Err(PredictorError::MissingTensor { tensor, path }) => {
                assert_eq!(tensor, "pool_net.mlp_pre_pool.2.weight");
                assert_eq!(path, PathBuf::from("<memory>"));
            }
            other => panic!("expected MissingTensor, got {other:?}"),
        }
    }
    // The teacher's fixed noise is required too.
    let mut p = Parts::teacher();
    p.tensors.retain(|t| t.0 != "fixed_noise");
    assert!(
        matches!(p.load(), Err(PredictorError::MissingTensor { tensor, .. }) if tensor == "fixed_noise")
    );
}

#[test]
fn wrong_shape() {
    let mut p = Parts::teacher();
    let t = p.tensor_mut("decoder.hidden2pos.weight");
    t.2 = vec![2, 31];
    t.3 = f32_bytes(&[0.1; 62]);
    match p.load() {
        Err(PredictorError::ShapeMismatch {
            tensor,
            expected,
            got,
            ..
        }) => {
            assert_eq!(tensor, "decoder.hidden2pos.weight");
            assert_eq!(expected, vec![2, 32]);
            assert_eq!(got, vec![2, 31]);
        }
        other => panic!("expected ShapeMismatch, got {other:?}"),
    }
    // Same element count, transposed.
    let mut p = Parts::student();
    let t = p.tensor_mut("encoder.encoder.weight_ih_l0");
    t.2 = vec![16, 64];
    assert!(
        matches!(p.load(), Err(PredictorError::ShapeMismatch { expected, .. }) if expected == vec![64, 16])
    );
}

#[test]
fn wrong_dtype() {
    let mut p = Parts::student();
    let t = p.tensor_mut("encoder.encoder.bias_ih_l0");
    t.1 = Dtype::F64;
    t.3 = (0..64).flat_map(|_| 0.5f64.to_le_bytes()).collect();
    match p.load() {
        Err(PredictorError::WrongDtype { tensor, got, .. }) => {
            assert_eq!(tensor, "encoder.encoder.bias_ih_l0");
            assert_eq!(got, "F64");
        }
        other => panic!("expected WrongDtype, got {other:?}"),
    }
    let mut p = Parts::teacher();
    let t = p.tensor_mut("fixed_noise");
    t.1 = Dtype::F16;
    t.3 = vec![0; 16];
    assert!(matches!(p.load(), Err(PredictorError::WrongDtype { got, .. }) if got == "F16"));
}

#[test]
fn truncated_and_not_safetensors() {
    let good = Parts::teacher().bytes();
    for cut in [good.len() - 1, good.len() / 2, 100, 9, 8, 3, 0] {
        assert!(
            matches!(
                ModelWeights::from_bytes(&good[..cut]),
                Err(PredictorError::NotSafetensors { .. })
            ),
            "cut at {cut}"
        );
    }
    for junk in [&b"hello, world, this is not a model"[..], &[0xff; 64][..]] {
        assert!(matches!(
            ModelWeights::from_bytes(junk),
            Err(PredictorError::NotSafetensors { .. })
        ));
    }
    // Header length pointing past the end.
    let mut bad = good.clone();
    bad[..8].copy_from_slice(&(good.len() as u64).to_le_bytes());
    assert!(matches!(
        ModelWeights::from_bytes(&bad),
        Err(PredictorError::NotSafetensors { .. })
    ));
}

#[test]
fn non_finite_weight() {
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut p = Parts::teacher();
        let t = p.tensor_mut("mlp_decoder_context.0.weight");
        t.3[20..24].copy_from_slice(&bad.to_le_bytes());
        match p.load() {
            Err(PredictorError::NonFiniteWeight { tensor, index, .. }) => {
                assert_eq!(tensor, "mlp_decoder_context.0.weight");
                assert_eq!(index, 5);
            }
            other => panic!("expected NonFiniteWeight, got {other:?}"),
        }
    }
}

#[test]
fn unknown_kind() {
    for kind in [serde_json::json!("oracle"), serde_json::json!(3)] {
        let mut p = Parts::student();
        let mut c = p.config();
        c["kind"] = kind.clone();
        p.set_config(&c);
        match p.load() {
            Err(PredictorError::UnknownModelKind { kind: k, .. }) => {
                assert!(k.contains(&kind.to_string().replace('"', "")), "{k}");
            }
            other => panic!("expected UnknownModelKind, got {other:?}"),
        }
    }
}

/// An in-place edit of a config JSON.
type ConfigEdit = fn(&mut serde_json::Value);

#[test]
fn bad_or_missing_config() {
    let mut cases: Vec<(&str, Parts)> = Vec::new();
    let mut p = Parts::teacher();
    p.meta.remove("config");
    cases.push(("missing config", p));
    let mut p = Parts::teacher();
    p.meta.insert("config".into(), "{not json".into());
    cases.push(("not json", p));
    let edits: [(&str, ConfigEdit); 9] = [
        ("missing kind", |c| {
            c.as_object_mut().unwrap().remove("kind");
        }),
        ("missing field", |c| {
            c.as_object_mut().unwrap().remove("pool_hidden_dim");
        }),
        ("unknown field", |c| {
            c["batch_norm"] = serde_json::json!(true)
        }),
        ("wrong type", |c| c["mlp_dim"] = serde_json::json!("64")),
        ("obs_len", |c| c["obs_len"] = serde_json::json!(9)),
        ("dt", |c| c["dt"] = serde_json::json!(0.1)),
        ("activation", |c| {
            c["activation"] = serde_json::json!("tanh")
        }),
        ("noise too big", |c| c["noise_dim"] = serde_json::json!(32)),
        ("teacher pred_len", |c| c["pred_len"] = serde_json::json!(6)),
    ];
    for (what, edit) in edits {
        let mut p = Parts::teacher();
        let mut c = p.config();
        edit(&mut c);
        p.set_config(&c);
        cases.push((what, p));
    }
    let mut p = Parts::student();
    let mut c = p.config();
    c["pred_len"] = serde_json::json!(1);
    p.set_config(&c);
    cases.push(("student pred_len", p));
    let mut p = Parts::student();
    p.meta.insert("format".into(), "nudge.weights/2".into());
    cases.push(("format", p));
    let mut p = Parts::student();
    p.meta.insert("trained".into(), "maybe".into());
    cases.push(("trained flag", p));
    for (what, p) in cases {
        match p.load() {
            Err(PredictorError::BadConfig { .. }) => {}
            other => panic!("{what}: expected BadConfig, got {other:?}"),
        }
    }
}

#[test]
fn unexpected_tensor() {
    let mut p = Parts::teacher();
    p.tensors.push((
        "extra.weight".into(),
        Dtype::F32,
        vec![2],
        f32_bytes(&[1.0, 2.0]),
    ));
    match p.load() {
        Err(PredictorError::UnexpectedTensor { tensor, kind, .. }) => {
            assert_eq!(tensor, "extra.weight");
            assert_eq!(kind, "teacher");
        }
        other => panic!("expected UnexpectedTensor, got {other:?}"),
    }
    // A student's decoder-pooling tensor in a teacher without pool_every_timestep.
    let student = Parts::student();
    let extra = student
        .tensors
        .iter()
        .find(|t| t.0 == "decoder.mlp.2.bias")
        .unwrap()
        .clone();
    let mut p = Parts::teacher();
    p.tensors.push(extra);
    assert!(
        matches!(p.load(), Err(PredictorError::UnexpectedTensor { tensor, .. }) if tensor == "decoder.mlp.2.bias")
    );
    // Noise in a noise-free student.
    let mut p = Parts::student();
    p.tensors
        .push(("fixed_noise".into(), Dtype::F32, vec![1], f32_bytes(&[0.3])));
    assert!(
        matches!(p.load(), Err(PredictorError::UnexpectedTensor { tensor, .. }) if tensor == "fixed_noise")
    );
}

#[test]
fn wrong_kind_and_io() {
    assert!(matches!(
        Teacher::from_bytes(&Parts::student().bytes()),
        Err(PredictorError::WrongModelKind {
            expected: "teacher",
            got: "student",
            ..
        })
    ));
    assert!(matches!(
        Student::from_bytes(&Parts::teacher().bytes()),
        Err(PredictorError::WrongModelKind { .. })
    ));
    let missing = std::env::temp_dir().join("nudge-no-such-dir/none.safetensors");
    assert!(matches!(
        Teacher::from_file(&missing),
        Err(PredictorError::Io { path, .. }) if path == missing
    ));
    assert!(matches!(
        load_predictor(&missing),
        Err(PredictorError::Io { .. })
    ));
    // Errors from a file name the file.
    let dir = std::env::temp_dir().join(format!("nudge-errors-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("broken.safetensors");
    let mut p = Parts::student();
    p.tensors.retain(|t| t.0 != "decoder.hidden2pos.bias");
    std::fs::write(&file, p.bytes()).unwrap();
    let err = load_predictor(&file).err().unwrap();
    assert!(matches!(&err, PredictorError::MissingTensor { path, .. } if *path == file));
    assert!(err.to_string().contains("broken.safetensors"), "{err}");
    assert!(err.to_string().contains("decoder.hidden2pos.bias"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

// ---------------------------------------------------------------------------------------
// Malformed inputs.
// ---------------------------------------------------------------------------------------

fn straight(n: usize) -> Vec<f64> {
    (0..n)
        .flat_map(|a| {
            (0..T_OBS).flat_map(move |t| [a as f64 * 7.0 + t as f64 * 2.0, (a % 3) as f64 * 3.5])
        })
        .collect()
}

fn predictors() -> Vec<Box<dyn Predictor>> {
    vec![
        Box::new(Teacher::from_bytes(&Parts::teacher().bytes()).unwrap()),
        Box::new(Student::from_bytes(&Parts::student().bytes()).unwrap()),
        Box::new(ConstantVelocity::default()),
    ]
}

#[test]
fn bad_history() {
    assert!(matches!(
        History::new(Vec::new(), 0),
        Err(PredictorError::AgentCount { got: 0, .. })
    ));
    assert!(matches!(
        History::new(straight(48), 48),
        Err(PredictorError::AgentCount {
            got: 48,
            max: MAX_AGENTS
        })
    ));
    assert!(History::new(straight(47), 47).is_ok());
    assert!(matches!(
        History::new(vec![0.0; 15], 1),
        Err(PredictorError::InputShape {
            what: "history",
            expected: 16,
            got: 15,
            ..
        })
    ));
    // 7 observed steps for 2 agents.
    assert!(matches!(
        History::new(vec![0.0; 28], 2),
        Err(PredictorError::InputShape {
            what: "history",
            ..
        })
    ));
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut h = straight(3);
        h[17] = bad;
        assert!(matches!(
            History::new(h, 3),
            Err(PredictorError::NonFiniteInput {
                what: "history",
                index: 17,
                ..
            })
        ));
    }
}

#[test]
fn bad_candidates_and_outputs() {
    let history = History::new(straight(4), 4).unwrap();
    let good = vec![1.0; 12];
    for mut p in predictors() {
        let name = p.name();
        let mut out = vec![0.0; 3 * 12];
        assert!(
            matches!(p.predict(&good, &mut out), Err(PredictorError::NoScene)),
            "{name}: predict before set_scene"
        );
        p.set_scene(&history).unwrap();
        for len in [0, 11, 13] {
            assert!(
                matches!(
                    p.predict(&vec![1.0; len], &mut out),
                    Err(PredictorError::InputShape {
                        what: "candidates",
                        ..
                    })
                ),
                "{name}: {len} candidate values"
            );
        }
        let mut nan = good.clone();
        nan[5] = f64::NAN;
        assert!(matches!(
            p.predict(&nan, &mut out),
            Err(PredictorError::NonFiniteInput {
                what: "candidates",
                index: 5,
                ..
            })
        ));
        nan[5] = f64::INFINITY;
        assert!(matches!(
            p.predict(&nan, &mut out),
            Err(PredictorError::NonFiniteInput {
                what: "candidates",
                ..
            })
        ));
        for len in [0, 35, 37, 72] {
            assert!(
                matches!(
                    p.predict(&good, &mut vec![0.0; len]),
                    Err(PredictorError::InputShape {
                        what: "out",
                        expected: 36,
                        ..
                    })
                ),
                "{name}: out of {len}"
            );
        }
        // Errors leave the predictor usable.
        p.predict(&good, &mut out).unwrap();
        assert!(out.iter().all(|v| v.is_finite()), "{name}");
    }
}

#[test]
fn bad_noise() {
    let mut t = Teacher::from_bytes(&Parts::teacher().bytes()).unwrap();
    assert!(matches!(
        t.set_noise(&[0.0; 7]),
        Err(PredictorError::InputShape {
            what: "noise",
            expected: 8,
            got: 7,
            ..
        })
    ));
    let mut z = [0.1; 8];
    z[2] = f64::NAN;
    assert!(matches!(
        t.set_noise(&z),
        Err(PredictorError::NonFiniteInput {
            what: "noise",
            index: 2,
            ..
        })
    ));
    let mut s = Student::from_bytes(&Parts::student().bytes()).unwrap();
    assert!(matches!(
        s.set_noise(&[1.0]),
        Err(PredictorError::InputShape {
            what: "noise",
            expected: 0,
            ..
        })
    ));
    assert!(s.set_noise(&[]).is_ok());
    // A new noise invalidates the cached scene.
    t.set_scene(&History::new(straight(2), 2).unwrap()).unwrap();
    t.set_noise(&[0.2; 8]).unwrap();
    assert!(matches!(
        t.predict(&[0.0; 12], &mut [0.0; 12]),
        Err(PredictorError::NoScene)
    ));
}

#[test]
fn single_agent_scene_predicts_nothing() {
    let history = History::new(straight(1), 1).unwrap();
    for mut p in predictors() {
        p.set_scene(&history).unwrap();
        let mut out: Vec<f64> = Vec::new();
        p.predict(&[0.0; 24], &mut out).unwrap();
        assert!(matches!(
            p.predict(&[0.0; 12], &mut [0.0; 1]),
            Err(PredictorError::InputShape { what: "out", .. })
        ));
    }
}
