//! Bounded fuzzing of the simulator's TOML configuration (run in CI): mutations of the default
//! configuration and arbitrary text give a configuration that validates or an error, never a panic.

use pi3det_sim::SimConfig;
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn sim_config_mutated(e in prop::collection::vec((any::<usize>(), any::<u8>(), any::<bool>()), 1..8)) {
        let mut b = SimConfig::default().to_toml_string().into_bytes();
        for (i, v, insert) in e {
            let at = i % b.len().max(1);
            if insert { b.insert(at, v) } else if !b.is_empty() { b[at] = v }
        }
        if let Ok(cfg) = SimConfig::from_toml_str(&String::from_utf8_lossy(&b)) {
            let _ = cfg.validate();
        }
    }

    #[test]
    fn sim_config_arbitrary(text in "\\PC{0,200}") {
        let _ = SimConfig::from_toml_str(&text);
    }
}
