//! Cross-checks with CPython + numpy: pickles written here must load in Python as the same
//! numpy arrays, and pickles Python writes (protocols 0–5) must decode here.
//!
//! Python is found via `PI3DET_PYTHON`, then `.venv/bin/python` at the repository root, then
//! `python3`; without a Python that can import numpy the tests print a note and pass.

use std::path::{Path, PathBuf};
use std::process::Command;

use pi3det_data::pickle::{self, ArrayData, NdArray, Value};

fn python() -> Option<PathBuf> {
    let imports_numpy =
        |py: &Path| Command::new(py).args(["-c", "import numpy"]).output().is_ok_and(|o| o.status.success());
    if let Some(py) = std::env::var_os("PI3DET_PYTHON") {
        let py = PathBuf::from(py);
        assert!(imports_numpy(&py), "PI3DET_PYTHON={} cannot import numpy", py.display());
        return Some(py);
    }
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let found = [venv, PathBuf::from("python3")].into_iter().find(|py| imports_numpy(py));
    if found.is_none() {
        eprintln!("note: no Python with numpy found (PI3DET_PYTHON, .venv, python3): skipping");
    }
    found
}

fn run_python(py: &Path, script: &str, args: &[&Path]) -> String {
    // -W error: loading our pickles must not even warn (e.g. about numpy.core being renamed).
    let out = Command::new(py).args(["-W", "error", "-c", script]).args(args).output().expect("run python");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "python failed:\nstdout:\n{stdout}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

fn arr(shape: &[usize], data: impl Into<ArrayData>) -> Value {
    Value::Array(NdArray::new(shape.to_vec(), data).unwrap())
}

fn s(x: &str) -> Value {
    Value::Str(x.into())
}

/// A Pi3DET-like info list plus one of everything the writer supports.
fn rust_value() -> Value {
    let frame = |id: &str, names: &[&str]| {
        let n = names.len();
        Value::dict([
            ("frame_id", s(id)),
            ("platform", s("drone")),
            (
                "calib",
                Value::dict([
                    ("E", arr(&[4, 4], (0..16).map(|i| i as f64 / 4.0).collect::<Vec<_>>())),
                    ("I", arr(&[3, 3], vec![700.0f64, 0., 600., 0., 700., 180., 0., 0., 1.])),
                ]),
            ),
            (
                "annos",
                Value::dict([
                    ("gt_names", arr(&[n], names.iter().map(|x| x.to_string()).collect::<Vec<_>>())),
                    ("gt_boxes_lidar", arr(&[n, 7], (0..n * 7).map(|i| i as f32 * 0.5).collect::<Vec<_>>())),
                ]),
            ),
        ])
    };
    Value::dict([
        ("infos", Value::List(vec![frame("0000001", &["Car", "Pedestrian", "Cyclist"]), frame("0000002", &[])])),
        ("f4", arr(&[2, 3], vec![1.0f32, 2.0, 3.0, 4.0, 5.0, 6.5])),
        ("f8", arr(&[3], vec![0.1f64, -1e300, f64::INFINITY])),
        ("i8", arr(&[2], vec![i64::MIN, i64::MAX])),
        ("i4", arr(&[], vec![-7i32])),
        ("u1", arr(&[3], vec![0u8, 128, 255])),
        ("b1", arr(&[2], vec![true, false])),
        ("names", arr(&[3], vec!["Car".to_string(), "".into(), "Fußgänger 😀".into()])),
        ("objects", arr(&[3], vec![Value::Int(1), s("x"), Value::dict([("k", Value::None)])])),
        (
            "nested",
            Value::dict([(
                "a",
                Value::dict([("b", Value::List(vec![1.5.into(), Value::Tuple(vec![]), Value::None]))]),
            )]),
        ),
        (
            "scalars",
            Value::Tuple(vec![Value::Int(1 << 40), Value::Float(-0.25), Value::Bool(true), Value::Bytes(vec![0, 255])]),
        ),
        ("set", Value::Set(vec![Value::Int(3)])),
        ("global", Value::Global("numpy.float32".into())),
    ])
}

const CHECK_RUST_PICKLE: &str = r#"
import pickle, sys
import numpy as np
with open(sys.argv[1], 'rb') as f:
    d = pickle.load(f)
infos = d['infos']
assert [i['frame_id'] for i in infos] == ['0000001', '0000002']
a = infos[0]['annos']
assert a['gt_names'].dtype == np.dtype('<U10'), a['gt_names'].dtype
assert a['gt_names'].tolist() == ['Car', 'Pedestrian', 'Cyclist']
assert a['gt_boxes_lidar'].dtype == np.float32 and a['gt_boxes_lidar'].shape == (3, 7)
assert a['gt_boxes_lidar'][2, 6] == 10.0
assert infos[1]['annos']['gt_boxes_lidar'].shape == (0, 7)
assert infos[1]['annos']['gt_names'].shape == (0,)
E = infos[0]['calib']['E']
assert E.dtype == np.float64 and E.shape == (4, 4) and E[3, 1] == 3.25 and E.flags['C_CONTIGUOUS']
assert d['f4'].dtype == np.float32 and d['f4'].tolist() == [[1, 2, 3], [4, 5, 6.5]]
assert d['f8'].dtype == np.float64 and d['f8'][0] == 0.1 and d['f8'][1] == -1e300 and np.isinf(d['f8'][2])
assert d['i8'].dtype == np.int64 and d['i8'].tolist() == [-2**63, 2**63 - 1]
assert d['i4'].dtype == np.int32 and d['i4'].shape == () and d['i4'] == -7
assert d['u1'].dtype == np.uint8 and d['u1'].tolist() == [0, 128, 255]
assert d['b1'].dtype == np.bool_ and d['b1'].tolist() == [True, False]
assert d['names'].dtype == np.dtype('<U11') and d['names'].tolist() == ['Car', '', 'Fußgänger 😀']
o = d['objects']
assert o.dtype == object and o.shape == (3,) and o.tolist() == [1, 'x', {'k': None}]
assert d['nested'] == {'a': {'b': [1.5, (), None]}}
assert d['scalars'] == (2**40, -0.25, True, b'\x00\xff')
assert d['set'] == {3}
assert d['global'] is np.float32
# Arrays must be fully usable (writeable, owning correct data).
d['f4'] += 1
assert d['f4'][0, 0] == 2
for p in (2, 4, 5):
    with open(sys.argv[1] + '.p%d' % p, 'wb') as f:
        pickle.dump(pickle.load(open(sys.argv[1], 'rb')), f, protocol=p)
print('ok')
"#;

#[test]
fn python_loads_rust_pickles() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rust.pkl");
    let value = rust_value();
    pickle::to_path(&path, &value, false).unwrap();
    assert_eq!(run_python(&py, CHECK_RUST_PICKLE, &[&path]).trim(), "ok");
    // What Python writes back from it decodes to the same value.
    for p in [2, 4, 5] {
        let again = pickle::from_path(dir.path().join(format!("rust.pkl.p{p}"))).unwrap();
        assert_eq!(again, value, "protocol {p}");
    }
}

const WRITE_PYTHON_PICKLES: &str = r#"
import pickle, sys, collections
import numpy as np
base = np.arange(12, dtype=np.int64).reshape(3, 4)
objs_f = np.asfortranarray(np.array([[1, 'a'], [2, 'b']], dtype=object))
l = [1, 2]
d = {
    'f32': np.float32(1.5), 'f64': np.float64(0.1), 'i64': np.int64(7), 'u8s': np.uint8(200),
    'b': np.bool_(True), 's': np.str_('hé'), 'bs': np.bytes_(b'ab'),
    'fortran': np.asfortranarray(np.arange(12.0).reshape(3, 4)),
    'fortran3': np.asfortranarray(np.arange(24, dtype=np.int32).reshape(2, 3, 4)),
    'big': np.array([[1.5, -2.0], [3.25, 4e10]], dtype='>f8'),
    'big_i4': np.array([1, -2, 70000], dtype='>i4'),
    'big_u': np.array(['ab', 'çé', ''], dtype='>U3'),
    'half': np.array([0.5, -2.0, 65504.0], dtype=np.float16),
    'bytes_arr': np.array([b'ab', b'hello'], dtype='S5'),
    'objs': np.array([1, 'x', None, [1, 2]], dtype=object),
    'objs_f': objs_f,
    'slice': base[:, ::2],
    'empty': np.zeros((0, 7), dtype=np.float32),
    'zero_d': np.array(3.5),
    'u64': np.array([2**64 - 1], dtype=np.uint64),
    'bools': np.array([True, False, True]),
    'od': collections.OrderedDict([('x', 1), ('y', 2)]),
    'dd': collections.defaultdict(list, {'k': [1]}),
    'raw': b'\x00\xffabc', 'ba': bytearray(b'xy'), 'empty_bytes': b'',
    'set': {1, 2, 3}, 'fz': frozenset({'a'}),
    'bigint': 2**62, 'neg': -2**40, 'tuple': (1, 'a', None, True),
    'unicode': '日本語 😀\n', 'shared': [l, l], 'float': 1e-300,
    'result': [{
        'frame_id': '000123',
        'name': np.array(['Car', 'Pedestrian']),
        'score': np.array([0.9, 0.25], dtype=np.float32),
        'boxes_lidar': np.arange(14, dtype=np.float32).reshape(2, 7),
        'pred_labels': np.array([1, 2]),
    }],
}
for p in range(6):
    with open('%s/py%d.pkl' % (sys.argv[1], p), 'wb') as f:
        pickle.dump(d, f, protocol=p)
print('ok')
"#;

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().to_f64_vec().unwrap()
}

fn check_python_value(d: &Value, protocol: usize) {
    let get = |k: &str| d.get(k).unwrap_or_else(|| panic!("protocol {protocol}: no {k}"));
    assert_eq!(get("f32"), &Value::Float(1.5));
    assert_eq!(get("f64"), &Value::Float(0.1));
    assert_eq!(get("i64"), &Value::Int(7));
    assert_eq!(get("u8s"), &Value::Int(200));
    assert_eq!(get("b"), &Value::Bool(true));
    assert_eq!(get("s"), &s("hé"));
    assert_eq!(get("bs"), &Value::Bytes(b"ab".to_vec()));
    let fortran = get("fortran").as_array().unwrap();
    assert_eq!((fortran.shape(), fortran.dtype_name()), (&[3, 4][..], "float64"));
    assert_eq!(f64s(get("fortran")), (0..12).map(f64::from).collect::<Vec<_>>());
    let fortran3 = get("fortran3").as_array().unwrap();
    assert_eq!(fortran3.shape(), &[2, 3, 4]);
    assert_eq!(fortran3.data, ArrayData::I32((0..24).collect()));
    assert_eq!(get("big").as_array().unwrap().data, ArrayData::F64(vec![1.5, -2.0, 3.25, 4e10]));
    assert_eq!(get("big_i4").as_array().unwrap().data, ArrayData::I32(vec![1, -2, 70000]));
    assert_eq!(get("big_u").as_array().unwrap().to_strings().unwrap(), ["ab", "çé", ""]);
    assert_eq!(get("half").as_array().unwrap().data, ArrayData::F32(vec![0.5, -2.0, 65504.0]));
    assert_eq!(get("bytes_arr").as_array().unwrap().data, ArrayData::Bytes(vec![b"ab".to_vec(), b"hello".to_vec()]));
    let one_two = Value::List(vec![Value::Int(1), Value::Int(2)]);
    assert_eq!(
        get("objs").as_array().unwrap().data,
        ArrayData::Object(vec![Value::Int(1), s("x"), Value::None, one_two.clone()])
    );
    let objs_f = get("objs_f").as_array().unwrap();
    assert_eq!(objs_f.shape(), &[2, 2]);
    assert_eq!(objs_f.data, ArrayData::Object(vec![Value::Int(1), s("a"), Value::Int(2), s("b")]));
    let slice = get("slice").as_array().unwrap();
    assert_eq!(slice.shape(), &[3, 2]);
    assert_eq!(slice.to_i64_vec().unwrap(), [0, 2, 4, 6, 8, 10]);
    let empty = get("empty").as_array().unwrap();
    assert_eq!((empty.shape(), empty.len()), (&[0, 7][..], 0));
    assert_eq!(get("zero_d").as_f64(), Some(3.5));
    assert_eq!(get("u64").as_array().unwrap().data, ArrayData::U64(vec![u64::MAX]));
    assert_eq!(get("bools").as_array().unwrap().data, ArrayData::Bool(vec![true, false, true]));
    assert_eq!(get("od"), &Value::dict([("x", Value::Int(1)), ("y", Value::Int(2))]));
    assert_eq!(get("dd"), &Value::dict([("k", Value::List(vec![Value::Int(1)]))]));
    assert_eq!(get("raw"), &Value::Bytes(b"\x00\xffabc".to_vec()));
    assert_eq!(get("ba"), &Value::Bytes(b"xy".to_vec()));
    assert_eq!(get("empty_bytes"), &Value::Bytes(vec![]));
    let Value::Set(set) = get("set") else { panic!("set") };
    let mut set: Vec<i64> = set.iter().filter_map(Value::as_i64).collect();
    set.sort();
    assert_eq!(set, [1, 2, 3]);
    assert_eq!(get("fz"), &Value::Set(vec![s("a")]));
    assert_eq!(get("bigint"), &Value::Int(1 << 62));
    assert_eq!(get("neg"), &Value::Int(-(1 << 40)));
    assert_eq!(get("tuple"), &Value::Tuple(vec![Value::Int(1), s("a"), Value::None, Value::Bool(true)]));
    assert_eq!(get("unicode"), &s("日本語 😀\n"));
    assert_eq!(get("shared"), &Value::List(vec![one_two.clone(), one_two]));
    assert_eq!(get("float"), &Value::Float(1e-300));

    // An OpenPCDet result.pkl entry.
    let result = &get("result").as_list().unwrap()[0];
    assert_eq!(result.get("frame_id").and_then(Value::as_str), Some("000123"));
    let name = result.get("name").and_then(Value::as_array).unwrap();
    assert_eq!(name.to_strings().unwrap(), ["Car", "Pedestrian"]);
    let score = result.get("score").and_then(Value::as_array).unwrap();
    assert_eq!(score.to_f32_vec().unwrap(), [0.9f32, 0.25]);
    let boxes = result.get("boxes_lidar").and_then(Value::as_array).unwrap();
    assert_eq!(boxes.shape(), &[2, 7]);
    assert_eq!(boxes.to_f64_rows().unwrap()[1][0], 7.0);
    let labels = result.get("pred_labels").and_then(Value::as_array).unwrap();
    assert_eq!(labels.to_i64_vec().unwrap(), [1, 2]);
}

#[test]
fn rust_reads_python_pickles() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(run_python(&py, WRITE_PYTHON_PICKLES, &[dir.path()]).trim(), "ok");
    let values: Vec<Value> = (0..6)
        .map(|p| {
            let v = pickle::from_path(dir.path().join(format!("py{p}.pkl")))
                .unwrap_or_else(|e| panic!("protocol {p}: {e}"));
            check_python_value(&v, p);
            v
        })
        .collect();
    // Every protocol decodes to the same tree, except for set order.
    for (p, v) in values.iter().enumerate() {
        let strip = |v: &Value| {
            let Value::Dict(pairs) = v else { panic!() };
            Value::Dict(pairs.iter().filter(|(k, _)| k.as_str() != Some("set")).cloned().collect())
        };
        assert_eq!(strip(v), strip(&values[4]), "protocol {p} differs from protocol 4");
    }
}
