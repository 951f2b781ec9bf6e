//! HDF5 files as the sequence reader opens them: any bytes as a file, its datasets' shapes and
//! first rows read with the reader's limits.
#![no_main]
use std::io::Write;
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(mut f) = tempfile::NamedTempFile::new() else { return };
    if f.write_all(data).is_err() {
        return;
    }
    if let Ok(h5) = pi3det_sequence::hdf5::H5File::open(f.path()) {
        for name in ["/ouster/data", "/ouster/metadata", "/ouster/ts_start", "/Ln_T_L0"] {
            if let Ok(d) = h5.dataset(name) {
                let _ = d.shape();
                let _ = d.read_row(0);
                let _ = d.read_text();
                let _ = d.read_f64();
            }
        }
    }
});
