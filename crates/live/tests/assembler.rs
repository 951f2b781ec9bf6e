//! The sweep-assembly rule, packet by packet: complete, partial (emitted or dropped), late,
//! duplicate, garbage, lost sweeps, the 16-bit frame-id wrap and a sensor restart.

use std::path::Path;

use pi3det_live::source::ouster_udp::Assembler;
use pi3det_sequence::ouster::SensorMetadata;
use pi3det_sequence::synth::{metadata_json, sweep_packets, SynthSpec};

fn spec() -> SynthSpec {
    SynthSpec { columns: 512, ..SynthSpec::os1_64("t", 1) }
}

fn packets(frame_id: u16) -> Vec<Vec<u8>> {
    let s = spec();
    let mut n = 0u64;
    // Sweeps 100 ms apart on the sensor clock, as a 10 Hz sensor stamps them.
    let t0 = 1_000_000_000 + u64::from(frame_id) * 100_000_000;
    let bytes = sweep_packets(&s, usize::from(frame_id), t0, &mut || {
        n += 1;
        n
    });
    let per = bytes.len() / (s.columns / 16);
    bytes.chunks_exact(per).map(<[u8]>::to_vec).collect()
}

fn assembler(min_coverage: f64) -> Assembler {
    let md = SensorMetadata::parse(Path::new("synth.json"), &metadata_json(&spec())).unwrap();
    Assembler::new(&md, min_coverage)
}

#[test]
fn a_complete_sweep_is_emitted_on_its_last_packet_in_any_order() {
    let mut a = assembler(0.75);
    let mut p = packets(7);
    p.reverse();
    let n = p.len();
    for (k, d) in p.iter().enumerate() {
        let out = a.push(d);
        assert_eq!(out.is_some(), k == n - 1, "packet {k}");
        if let Some(s) = out {
            assert_eq!((s.frame_id, s.received, s.expected), (7, n, n));
        }
    }
    assert_eq!(a.report.get("complete"), 1);
}

#[test]
fn partial_sweeps_follow_the_coverage_rule() {
    let mut a = assembler(0.75);
    let p = packets(1);
    let n = p.len();
    // 80 % of sweep 1, then sweep 2 begins: sweep 1 is emitted as partial.
    for d in &p[..n * 8 / 10] {
        assert!(a.push(d).is_none());
    }
    let s = a.push(&packets(2)[0]).expect("partial sweep emitted");
    assert_eq!((s.frame_id, s.received), (1, n * 8 / 10));
    // 50 % of sweep 2, then sweep 3: dropped.
    for d in &packets(2)[1..n / 2] {
        assert!(a.push(d).is_none());
    }
    assert!(a.push(&packets(3)[0]).is_none());
    assert_eq!(a.report.get("partial"), 1);
    assert_eq!(a.report.get("dropped_partial"), 1);
    // A quiet stream ends the pending sweep the same way.
    for d in &packets(3)[1..] {
        let _ = a.push(d);
    }
    assert_eq!(a.report.get("complete"), 1);
    assert!(a.end_pending().is_none(), "nothing pending after a complete sweep");
}

#[test]
fn late_duplicate_and_garbage_packets_are_counted_and_dropped() {
    let mut a = assembler(0.75);
    let p1 = packets(1);
    let p2 = packets(2);
    for d in &p1[..p1.len() - 1] {
        assert!(a.push(d).is_none());
        assert!(a.push(d).is_none(), "duplicate");
    }
    assert!(a.push(&p2[0]).is_some(), "sweep 1 ends as partial");
    assert!(a.push(&p1[p1.len() - 1]).is_none(), "late packet of sweep 1");
    assert!(a.push(&[1, 2, 3]).is_none());
    assert!(a.push(&p2[1][..100]).is_none());
    let mut wrong_slot = p2[1].clone();
    wrong_slot[8] = 3; // a measurement id that does not start a packet
    assert!(a.push(&wrong_slot).is_none());
    assert_eq!(a.report.get("duplicate"), (p1.len() - 1) as u64);
    assert_eq!(a.report.get("late"), 1);
    assert_eq!(a.report.get("garbage"), 3);
}

#[test]
fn frame_ids_wrap_skip_and_restart() {
    let mut a = assembler(0.75);
    let mut emitted = Vec::new();
    for id in [65534u16, 65535, 0, 1, 4, 5, 0, 1] {
        for d in packets(id) {
            if let Some(s) = a.push(&d) {
                emitted.push(s.frame_id);
            }
        }
    }
    assert_eq!(emitted, vec![65534, 65535, 0, 1, 4, 5, 0, 1]);
    assert_eq!(a.report.get("wraps"), 1);
    assert_eq!(a.report.get("lost_sweeps"), 2);
    assert_eq!(a.report.get("restarts"), 1);
    assert_eq!(a.report.get("complete"), 8);
}

#[test]
fn a_restart_whose_clock_began_again_is_taken_after_half_a_sweep() {
    let mut a = assembler(0.4);
    for id in [1u16, 2] {
        for d in packets(id) {
            let _ = a.push(&d);
        }
    }
    // The sensor restarts: frame id 1 again, stamped before everything seen.
    let s = spec();
    let bytes = sweep_packets(&s, 1, 5, &mut || 9);
    let per = bytes.len() / (s.columns / 16);
    let restarted: Vec<&[u8]> = bytes.chunks_exact(per).collect();
    let emitted: Vec<_> = restarted.iter().filter_map(|d| a.push(d)).collect();
    let n = restarted.len();
    assert_eq!(a.report.get("late"), (n / 2) as u64);
    assert!(emitted.is_empty());
    let s = a.end_pending().expect("the restarted sweep's second half is emitted (coverage 0.4)");
    assert_eq!((s.frame_id, s.received), (1, n - n / 2));
}
