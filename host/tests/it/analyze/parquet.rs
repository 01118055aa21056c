//! Parquet exports read back by an independent reader, and the report.

use super::{frames, write_recording};
use crate::common::run;
use std::path::{Path, PathBuf};

// ------------------------------------------------------------ Parquet exports

/// A Parquet reader of another implementation than the writer's
/// (`parquet2`'s page reader; the values decoded here from the page
/// buffers): a bug in our writer path shows as a mismatch, not as the
/// same bug read back.
pub(crate) mod pq {
    use parquet2::encoding::Encoding;
    use parquet2::encoding::hybrid_rle::HybridRleDecoder;
    use parquet2::page::{Page, split_buffer};
    use parquet2::read::{decompress, get_page_iterator, read_metadata};
    use parquet2::schema::Repetition;
    use parquet2::schema::types::{PhysicalType, PrimitiveLogicalType};
    use std::collections::HashMap;
    use std::path::Path;

    /// One column's values, nulls as `None`.
    #[derive(Debug, Clone, PartialEq)]
    pub enum Col {
        F64(Vec<Option<f64>>),
        I32(Vec<Option<i32>>),
        Bool(Vec<Option<bool>>),
        Str(Vec<Option<String>>),
        ListF64(Vec<Option<Vec<f64>>>),
    }

    /// A value before it is placed among the nulls.
    #[derive(Debug, Clone)]
    enum V {
        F(f64),
        I(i32),
        B(bool),
        S(String),
    }

    /// A column: name, type as `DOUBLE`/`INT32`/`BOOLEAN`/`STRING`/`LIST<DOUBLE>`, nullable, values.
    pub struct Column {
        pub name: String,
        pub ty: &'static str,
        pub nullable: bool,
        pub values: Col,
    }

    pub struct File {
        pub rows: usize,
        pub columns: Vec<Column>,
        pub meta: HashMap<String, String>,
    }

    impl File {
        pub fn col(&self, name: &str) -> &Col {
            &self.columns.iter().find(|c| c.name == name).unwrap_or_else(|| panic!("no column {name}")).values
        }
        pub fn f64(&self, name: &str) -> &[Option<f64>] {
            match self.col(name) {
                Col::F64(v) => v,
                c => panic!("{name} is not DOUBLE: {c:?}"),
            }
        }
        pub fn str(&self, name: &str) -> &[Option<String>] {
            match self.col(name) {
                Col::Str(v) => v,
                c => panic!("{name} is not STRING: {c:?}"),
            }
        }
        pub fn list(&self, name: &str) -> &[Option<Vec<f64>>] {
            match self.col(name) {
                Col::ListF64(v) => v,
                c => panic!("{name} is not LIST<DOUBLE>: {c:?}"),
            }
        }
        /// `(name, type, nullable)` of every column, in order.
        pub fn schema(&self) -> Vec<(String, &'static str, bool)> {
            self.columns.iter().map(|c| (c.name.clone(), c.ty, c.nullable)).collect()
        }
    }

    fn plain(buf: &[u8], n: usize, ty: &PhysicalType) -> Vec<V> {
        let mut out = Vec::with_capacity(n);
        let mut at = 0usize;
        for i in 0..n {
            out.push(match ty {
                PhysicalType::Double => {
                    at += 8;
                    V::F(f64::from_le_bytes(buf[at - 8..at].try_into().unwrap()))
                }
                PhysicalType::Int32 => {
                    at += 4;
                    V::I(i32::from_le_bytes(buf[at - 4..at].try_into().unwrap()))
                }
                PhysicalType::Boolean => V::B(buf[i / 8] >> (i % 8) & 1 == 1),
                PhysicalType::ByteArray => {
                    let len = u32::from_le_bytes(buf[at..at + 4].try_into().unwrap()) as usize;
                    at += 4 + len;
                    V::S(String::from_utf8(buf[at - len..at].to_vec()).unwrap())
                }
                t => panic!("unexpected physical type {t:?}"),
            });
        }
        out
    }

    pub fn read(path: &Path) -> File {
        let mut f = std::fs::File::open(path).unwrap();
        let meta = read_metadata(&mut f).unwrap();
        let kv = meta.key_value_metadata().clone().unwrap_or_default();
        let meta_map = kv.into_iter().map(|k| (k.key, k.value.unwrap_or_default())).collect();
        let mut columns: Vec<Column> = Vec::new();
        let mut values: Vec<Vec<Option<V>>> = Vec::new();
        let mut lists: HashMap<usize, Vec<Option<Vec<f64>>>> = HashMap::new();
        for rg in &meta.row_groups {
            for (c, cc) in rg.columns().iter().enumerate() {
                let d = cc.descriptor();
                let prim = &d.descriptor.primitive_type;
                if d.descriptor.max_rep_level == 1 {
                    let (name, nullable, rows) = read_list(&mut f, cc, &meta);
                    if columns.len() <= c {
                        columns.push(Column { name, ty: "LIST<DOUBLE>", nullable, values: Col::F64(vec![]) });
                        values.push(Vec::new());
                    }
                    lists.entry(c).or_default().extend(rows);
                    continue;
                }
                assert_eq!(d.descriptor.max_rep_level, 0);
                let nullable = prim.field_info.repetition == Repetition::Optional;
                assert_eq!(d.descriptor.max_def_level, i16::from(nullable));
                let ty = match (&prim.physical_type, &prim.logical_type) {
                    (PhysicalType::Double, None) => "DOUBLE",
                    (PhysicalType::Int32, None) => "INT32",
                    (PhysicalType::Boolean, None) => "BOOLEAN",
                    (PhysicalType::ByteArray, Some(PrimitiveLogicalType::String)) => "STRING",
                    t => panic!("unexpected type {t:?}"),
                };
                if columns.len() <= c {
                    columns.push(Column { name: d.path_in_schema.join("."), ty, nullable, values: Col::F64(vec![]) });
                    values.push(Vec::new());
                }
                let mut dict: Vec<V> = Vec::new();
                let mut buffer = Vec::new();
                for page in get_page_iterator(cc, &mut f, None, vec![], 1 << 30).unwrap() {
                    match decompress(page.unwrap(), &mut buffer).unwrap() {
                        Page::Dict(p) => dict = plain(&p.buffer, p.num_values, &prim.physical_type),
                        Page::Data(p) => {
                            let n = p.num_values();
                            let (_, def, vals) = split_buffer(&p).unwrap();
                            let present: Vec<bool> = if nullable {
                                HybridRleDecoder::try_new(def, 1, n).unwrap().map(|d| d.unwrap() == 1).collect()
                            } else {
                                vec![true; n]
                            };
                            let k = present.iter().filter(|&&p| p).count();
                            let decoded = match p.encoding() {
                                Encoding::Plain => plain(vals, k, &prim.physical_type),
                                Encoding::RleDictionary | Encoding::PlainDictionary => {
                                    let bits = u32::from(vals[0]);
                                    HybridRleDecoder::try_new(&vals[1..], bits, k)
                                        .unwrap()
                                        .map(|i| dict[i.unwrap() as usize].clone())
                                        .collect()
                                }
                                e => panic!("unexpected encoding {e:?}"),
                            };
                            assert_eq!(decoded.len(), k);
                            let mut it = decoded.into_iter();
                            values[c].extend(present.iter().map(|&p| if p { it.next() } else { None }));
                        }
                    }
                }
            }
        }
        for (i, (c, v)) in columns.iter_mut().zip(values).enumerate() {
            c.values = match c.ty {
                "LIST<DOUBLE>" => Col::ListF64(lists.remove(&i).unwrap_or_default()),
                "DOUBLE" => {
                    Col::F64(v.into_iter().map(|v| v.map(|v| if let V::F(x) = v { x } else { panic!() })).collect())
                }
                "INT32" => {
                    Col::I32(v.into_iter().map(|v| v.map(|v| if let V::I(x) = v { x } else { panic!() })).collect())
                }
                "BOOLEAN" => {
                    Col::Bool(v.into_iter().map(|v| v.map(|v| if let V::B(x) = v { x } else { panic!() })).collect())
                }
                _ => Col::Str(v.into_iter().map(|v| v.map(|v| if let V::S(x) = v { x } else { panic!() })).collect()),
            };
        }
        File { rows: meta.num_rows, columns, meta: meta_map }
    }

    /// A `LIST` of required `DOUBLE`s (the three-level layout: an
    /// optional or required group annotated LIST, a repeated group, the
    /// element), rebuilt from its repetition and definition levels.
    fn read_list(
        f: &mut std::fs::File,
        cc: &parquet2::metadata::ColumnChunkMetaData,
        meta: &parquet2::metadata::FileMetaData,
    ) -> (String, bool, Vec<Option<Vec<f64>>>) {
        use parquet2::schema::types::{GroupLogicalType, ParquetType};
        let d = cc.descriptor();
        let name = d.path_in_schema[0].clone();
        let Some(ParquetType::GroupType { field_info, logical_type, .. }) =
            meta.schema().fields().iter().find(|t| t.name() == name)
        else {
            panic!("{name}: not a group");
        };
        assert_eq!(*logical_type, Some(GroupLogicalType::List), "{name}");
        let nullable = field_info.repetition == Repetition::Optional;
        let max_def = d.descriptor.max_def_level;
        assert_eq!(max_def, 1 + i16::from(nullable), "{name}: elements are required");
        assert_eq!(d.descriptor.primitive_type.physical_type, PhysicalType::Double);
        let mut rows: Vec<Option<Vec<f64>>> = Vec::new();
        let mut buffer = Vec::new();
        let mut dict: Vec<V> = Vec::new();
        for page in get_page_iterator(cc, f, None, vec![], 1 << 30).unwrap() {
            let p = match decompress(page.unwrap(), &mut buffer).unwrap() {
                Page::Dict(p) => {
                    dict = plain(&p.buffer, p.num_values, &PhysicalType::Double);
                    continue;
                }
                Page::Data(p) => p,
            };
            let n = p.num_values();
            let (rep, def, vals) = split_buffer(&p).unwrap();
            let reps: Vec<u32> = HybridRleDecoder::try_new(rep, 1, n).unwrap().map(|r| r.unwrap()).collect();
            let defs: Vec<u32> = HybridRleDecoder::try_new(def, 2, n).unwrap().map(|d| d.unwrap()).collect();
            let k = defs.iter().filter(|&&d| d == max_def as u32).count();
            let decoded = match p.encoding() {
                Encoding::Plain => plain(vals, k, &PhysicalType::Double),
                Encoding::RleDictionary | Encoding::PlainDictionary => {
                    HybridRleDecoder::try_new(&vals[1..], u32::from(vals[0]), k)
                        .unwrap()
                        .map(|i| dict[i.unwrap() as usize].clone())
                        .collect()
                }
                e => panic!("{name}: unexpected encoding {e:?}"),
            };
            let mut it = decoded.into_iter();
            for (r, d) in reps.into_iter().zip(defs) {
                if r == 0 {
                    rows.push(if nullable && d == 0 { None } else { Some(Vec::new()) });
                }
                if d == max_def as u32 {
                    let Some(V::F(x)) = it.next() else { panic!("{name}: fewer values than levels") };
                    rows.last_mut().unwrap().as_mut().unwrap().push(x);
                }
            }
        }
        (name, nullable, rows)
    }
}

/// 7 m of the test rail (30 µm at 50 mm: over the 30–100 mm limit) in
/// three lines, with a gap in all of them (frames 100–104 missing) and one
/// in line 2 only (no points of it in frames 250–255).
pub(super) fn gappy_recording(dir: &Path) -> PathBuf {
    let rec = dir.join("gappy.cmsrec");
    let skip: Vec<u32> = (100..105).collect();
    let mut fs = frames(17.0, 420, &skip, 0.5, 7);
    for f in fs.iter_mut().filter(|f| (250..256).contains(&f.seq)) {
        f.lasers[2].clear();
    }
    write_recording(&rec, &fs, true);
    rec
}

/// `analyze --parquet DIR` (and `--report DIR`) on a recording of three
/// lines with a gap in all of them and one in line 2 only, the rail
/// corrugated over the 30–100 mm limit: profile.parquet, blocks.parquet
/// and zones.parquet read back with parquet2 have exactly the columns,
/// types and nullability of docs/exports.md; the heights are the report's
/// profile.csv (another writer), null exactly in the JSON's gaps, the
/// coverage their count; blocks and zones are the JSON's verdict. The
/// report's copies are the same bytes.
#[test]
fn parquet_exports_read_back_with_an_independent_reader() {
    let dir = tempfile::tempdir().unwrap();
    let rec = gappy_recording(dir.path());
    let (pqdir, report) = (dir.path().join("pq/sub"), dir.path().join("report"));
    let r = rec.to_str().unwrap();
    let o = run(&[
        "analyze",
        r,
        "--json",
        "--block-m",
        "2",
        "--parquet",
        pqdir.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let dx = v["dx_mm"].as_f64().unwrap();
    let lasers = v["lasers"].as_array().unwrap();
    assert_eq!(lasers.len(), 3);

    // profile.parquet
    let p = pq::read(&pqdir.join("profile.parquet"));
    let s = |n: &str, t: &'static str, null: bool| (n.to_string(), t, null);
    assert_eq!(
        p.schema(),
        vec![
            s("source", "STRING", false),
            s("chainage_mm", "DOUBLE", false),
            s("height_um_0", "DOUBLE", true),
            s("height_um_1", "DOUBLE", true),
            s("height_um_2", "DOUBLE", true),
            s("coverage", "INT32", false),
        ]
    );
    assert_eq!(p.meta["cms.schema"], "cms-host analyze exports 4");
    assert_eq!(p.meta["cms.dx_mm"].parse::<f64>().unwrap(), dx);
    let origin = lasers.iter().map(|l| l["x0_mm"].as_f64().unwrap()).fold(f64::INFINITY, f64::min);
    let idx = |x: f64| ((x - origin) / dx).round() as usize;
    let rows = lasers.iter().map(|l| idx(l["x0_mm"].as_f64().unwrap()) + l["samples"].as_u64().unwrap() as usize).max();
    assert_eq!(Some(p.rows), rows);
    assert!(p.str("source").iter().all(|s| s.as_deref() == Some(r)));
    let x = p.f64("chainage_mm");
    assert_eq!(x.len(), p.rows);
    for (i, x) in x.iter().enumerate() {
        assert!((x.unwrap() - (origin + i as f64 * dx)).abs() < 1e-6, "row {i}: {x:?}");
    }
    // The report's profile.csv: x_mm, laser_K_um (4 decimals), empty in gaps.
    let csv = std::fs::read_to_string(report.join("profile.csv")).unwrap();
    let csv: Vec<Vec<&str>> = csv.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(csv.len(), p.rows);
    let mut coverage = vec![0i32; p.rows];
    let mut nulls_in_gaps = 0;
    for (k, l) in lasers.iter().enumerate() {
        let h = p.f64(&format!("height_um_{k}"));
        let gaps: Vec<(f64, f64)> = l["gaps"]
            .as_array()
            .unwrap()
            .iter()
            .map(|g| (g["start_mm"].as_f64().unwrap(), g["length_mm"].as_f64().unwrap()))
            .collect();
        assert!(!gaps.is_empty(), "line {k} has a gap");
        let (x0, n) = (l["x0_mm"].as_f64().unwrap(), l["samples"].as_u64().unwrap() as usize);
        for i in 0..p.rows {
            let xi = origin + i as f64 * dx;
            let inside = xi >= x0 - 1e-6 && idx(xi) < idx(x0) + n;
            let in_gap = gaps.iter().any(|&(g0, len)| xi > g0 + 1e-6 && xi < g0 + len - 1e-6);
            match (h[i], csv[i][k + 1]) {
                (Some(z), text) => {
                    assert!(inside && !in_gap, "line {k} row {i} ({xi} mm): a height {z} outside or in a gap");
                    let want: f64 = text.parse().unwrap_or_else(|_| panic!("csv row {i} line {k}: `{text}`"));
                    assert!((z - want).abs() <= 5.1e-5, "line {k} row {i}: {z} vs csv {want}");
                    coverage[i] += 1;
                }
                (None, text) => {
                    assert_eq!(text, "", "line {k} row {i}: null where the csv has a height");
                    // Null only in a gap (or outside the line's span), never NaN.
                    assert!(!inside || gaps.iter().any(|&(g0, len)| xi >= g0 - dx && xi <= g0 + len + dx), "{k} {i}");
                    nulls_in_gaps += usize::from(in_gap);
                }
            }
            if in_gap {
                assert_eq!(h[i], None, "line {k} row {i} ({xi} mm) is in a gap");
            }
        }
    }
    assert!(nulls_in_gaps > 60, "{nulls_in_gaps}");
    let pq::Col::I32(cov) = p.col("coverage") else { panic!("coverage type") };
    let cov: Vec<i32> = cov.iter().map(|c| c.unwrap()).collect();
    assert_eq!(cov, coverage);
    assert!(cov.contains(&0) && cov.contains(&2) && cov.contains(&3), "gaps of all lines and of one");

    // blocks.parquet
    let verdict = &v["verdict"];
    let b = pq::read(&pqdir.join("blocks.parquet"));
    // The energy average's ISO 3095 columns, then each line's (`_K`).
    let iso = |k: &str| {
        let c = |n: &str, t| s(&format!("iso3095_{n}{k}"), t, true);
        [
            c("verdict", "STRING"),
            c("within_mm", "LIST<DOUBLE>"),
            c("exceeded_mm", "LIST<DOUBLE>"),
            c("not_judged_mm", "LIST<DOUBLE>"),
        ]
    };
    let mut want = vec![
        s("source", "STRING", false),
        s("start_chainage_mm", "DOUBLE", false),
        s("end_chainage_mm", "DOUBLE", false),
        s("rms_um_10_30", "DOUBLE", true),
        s("rms_um_30_100", "DOUBLE", true),
        s("rms_um_100_300", "DOUBLE", true),
        s("rms_um_300_1000", "DOUBLE", true),
        s("floor_rms_um_10_30", "DOUBLE", true),
        s("floor_rms_um_30_100", "DOUBLE", true),
        s("floor_rms_um_100_300", "DOUBLE", true),
        s("floor_rms_um_300_1000", "DOUBLE", true),
    ];
    for k in ["", "_0", "_1", "_2"] {
        want.extend(iso(k));
    }
    assert_eq!(b.schema(), want);
    let blocks = verdict["blocks"].as_array().unwrap();
    assert!(blocks.len() >= 3, "{blocks:?}");
    assert_eq!(b.rows, blocks.len());
    let wavelengths =
        |v: &serde_json::Value| v.as_array().map(|e| e.iter().map(|w| w.as_f64().unwrap()).collect::<Vec<_>>());
    let mut verdicts = std::collections::BTreeSet::new();
    let bands = ["10_30", "30_100", "100_300", "300_1000"];
    let mut rms_seen = 0;
    let mut several_exceeded = false;
    for (i, j) in blocks.iter().enumerate() {
        assert_eq!(b.f64("start_chainage_mm")[i], j["start_mm"].as_f64());
        assert_eq!(b.f64("end_chainage_mm")[i], j["end_mm"].as_f64());
        assert_eq!(b.str("source")[i].as_deref(), Some(r));
        for (k, band) in bands.iter().enumerate() {
            let got = b.f64(&format!("rms_um_{band}"))[i];
            match j["rms_mm"][k].as_f64() {
                Some(mm) => {
                    assert!((got.unwrap() - mm * 1000.0).abs() < 1e-9, "block {i} {band}: {got:?} vs {mm} mm");
                    rms_seen += 1;
                }
                None => assert_eq!(got, None, "block {i} {band}"),
            }
        }
        // The energy average's and each line's verdict and third octaves, the JSON's.
        let lines = j["lines"].as_array().unwrap();
        let of = |k: &str| match k {
            "" => &j["iso3095"],
            k => lines
                .iter()
                .find(|l| format!("_{}", l["laser"]) == k)
                .map_or(&serde_json::Value::Null, |l| &l["iso3095"]),
        };
        for k in ["", "_0", "_1", "_2"] {
            let o = of(k);
            assert_eq!(b.str(&format!("iso3095_verdict{k}"))[i].as_deref(), o["verdict"].as_str(), "block {i}{k}");
            for class in ["within_mm", "exceeded_mm", "not_judged_mm"] {
                assert_eq!(b.list(&format!("iso3095_{class}{k}"))[i], wavelengths(&o[class]), "block {i} {class}{k}");
            }
            verdicts.extend(o["verdict"].as_str().map(String::from));
        }
        several_exceeded |= wavelengths(&j["iso3095"]["exceeded_mm"]).is_some_and(|l| l.len() > 1);
    }
    assert!(several_exceeded, "a block with several wavelengths over the limit");
    assert!(verdicts.contains("EXCEEDS"), "{verdicts:?}");
    assert!(rms_seen >= blocks.len(), "{rms_seen}");

    // zones.parquet
    let z = pq::read(&pqdir.join("zones.parquet"));
    assert_eq!(
        z.schema(),
        vec![
            s("source", "STRING", false),
            s("edition", "STRING", false),
            s("band_lo_mm", "DOUBLE", false),
            s("band_hi_mm", "DOUBLE", false),
            s("start_chainage_mm", "DOUBLE", false),
            s("end_chainage_mm", "DOUBLE", false),
            s("exceeding_mm", "DOUBLE", false),
            s("worst_pp_mm", "DOUBLE", false),
        ]
    );
    let zones = verdict["zones"].as_array().unwrap();
    assert!(!zones.is_empty(), "30 µm at 50 mm exceeds the 30–100 mm limit");
    assert_eq!(z.rows, zones.len());
    for (i, j) in zones.iter().enumerate() {
        assert_eq!(z.str("edition")[i].as_deref(), verdict["edition"].as_str());
        for (col, key) in [
            ("band_lo_mm", "lo_mm"),
            ("band_hi_mm", "hi_mm"),
            ("start_chainage_mm", "start_mm"),
            ("end_chainage_mm", "end_mm"),
            ("exceeding_mm", "exceeding_mm"),
            ("worst_pp_mm", "worst_pp_mm"),
        ] {
            assert_eq!(z.f64(col)[i], j[key].as_f64(), "zone {i} {col}");
        }
    }
    // fixes.parquet: the columns, and no row for a recording without fixes.
    let fx = pq::read(&pqdir.join("fixes.parquet"));
    assert_eq!(fx.rows, 0);
    assert_eq!(fx.schema(), fixes_schema());
    third_octaves_are_the_jsons(&pqdir, &v, r);
    // The report writes the same files.
    for f in ["profile.parquet", "blocks.parquet", "zones.parquet", "fixes.parquet", "third_octaves.parquet"] {
        assert_eq!(std::fs::read(pqdir.join(f)).unwrap(), std::fs::read(report.join(f)).unwrap(), "{f}");
    }
}

/// `third_octaves.parquet`: its columns (docs/exports.md), one row per
/// block, spectrum (the energy average, then each line) and ISO 3095 third
/// octave, each value the JSON's `verdict.blocks[].iso3095.bands` (and
/// `lines[].iso3095.bands`) exactly.
fn third_octaves_are_the_jsons(pqdir: &Path, v: &serde_json::Value, source: &str) {
    let t = pq::read(&pqdir.join("third_octaves.parquet"));
    let s = |n: &str, t: &'static str, null: bool| (n.to_string(), t, null);
    assert_eq!(
        t.schema(),
        vec![
            s("source", "STRING", false),
            s("start_chainage_mm", "DOUBLE", false),
            s("end_chainage_mm", "DOUBLE", false),
            s("laser", "INT32", true),
            s("wavelength_mm", "DOUBLE", false),
            s("level_db", "DOUBLE", true),
            s("floor_db", "DOUBLE", true),
            s("limit_db", "DOUBLE", false),
            s("rail_db", "DOUBLE", true),
            s("rail_lo_db", "DOUBLE", true),
            s("rail_hi_db", "DOUBLE", true),
            s("verdict", "STRING", false),
        ]
    );
    let pq::Col::I32(laser) = t.col("laser") else { panic!("laser type") };
    let mut i = 0;
    let mut kinds = std::collections::BTreeSet::new();
    for b in v["verdict"]["blocks"].as_array().unwrap() {
        let lines = b["lines"].as_array().unwrap().iter().map(|l| (l["laser"].as_i64(), &l["iso3095"]));
        for (k, iso) in std::iter::once((None, &b["iso3095"])).chain(lines).filter(|(_, o)| !o.is_null()) {
            for band in iso["bands"].as_array().unwrap().iter().filter(|o| !o["decision"].is_null()) {
                let d = &band["decision"];
                assert_eq!(t.str("source")[i].as_deref(), Some(source));
                assert_eq!(t.f64("start_chainage_mm")[i], b["start_mm"].as_f64(), "row {i}");
                assert_eq!(t.f64("end_chainage_mm")[i], b["end_mm"].as_f64(), "row {i}");
                assert_eq!(laser[i].map(i64::from), k, "row {i}");
                for (col, json) in [
                    ("wavelength_mm", &band["nominal_wavelength_mm"]),
                    ("level_db", &band["level_db"]),
                    ("floor_db", &band["floor_db"]),
                    ("limit_db", &band["iso3095_limit_db"]),
                    ("rail_db", &d["rail_db"]),
                    ("rail_lo_db", &d["rail_lo_db"]),
                    ("rail_hi_db", &d["rail_hi_db"]),
                ] {
                    // serde_json parses a float to within an ulp of what was printed.
                    let (got, want) = (t.f64(col)[i], json.as_f64());
                    let same = match (got, want) {
                        (Some(a), Some(b)) => (a - b).abs() <= 1e-12 * b.abs().max(1.0),
                        (a, b) => a == b,
                    };
                    assert!(same, "row {i} {col}: {got:?} against the JSON's {want:?}");
                }
                assert_eq!(t.str("verdict")[i].as_deref(), d["verdict"].as_str(), "row {i}");
                kinds.insert((k.is_some(), d["verdict"].as_str().unwrap().to_string()));
                i += 1;
            }
        }
    }
    assert_eq!(t.rows, i);
    // Every block's energy average and lines, over 20 third octaves each at most.
    assert!(i >= 4 * v["verdict"]["blocks"].as_array().unwrap().len(), "{i} rows");
    assert!(kinds.contains(&(false, "EXCEEDS".into())) && kinds.contains(&(true, "EXCEEDS".into())), "{kinds:?}");
}

/// `fixes.parquet`'s columns (docs/exports.md): name, type, nullable.
pub(crate) fn fixes_schema() -> Vec<(String, &'static str, bool)> {
    [
        ("source", "STRING", false),
        ("run", "INT32", false),
        ("host_time_s", "DOUBLE", false),
        ("head_time_s", "DOUBLE", true),
        ("odometer_mm", "DOUBLE", true),
        ("chainage_mm", "DOUBLE", true),
        ("utc_date", "STRING", true),
        ("utc_time_of_day_s", "DOUBLE", true),
        ("lat_deg", "DOUBLE", false),
        ("lon_deg", "DOUBLE", false),
        ("altitude_m", "DOUBLE", true),
        ("quality", "STRING", false),
        ("satellites", "INT32", true),
        ("hdop", "DOUBLE", true),
        ("sigma_m", "DOUBLE", false),
        ("speed_mm_s", "DOUBLE", true),
        ("course_deg", "DOUBLE", true),
    ]
    .into_iter()
    .map(|(n, t, o)| (n.to_string(), t, o))
    .collect()
}

/// A --parquet directory that is a file, or lies under one, is bad usage
/// (exit status 2, as for --report), before the work; one that cannot be
/// written (no permission) is an output error: one line, exit status 1;
/// nothing half-written is left.
#[test]
fn an_unwritable_parquet_dir_is_an_output_error() {
    use crate::common::one_line_failure;
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("ok.cmsrec");
    write_recording(&rec, &frames(33.3, 20, &[], 1.0, 5), true);
    let file = dir.path().join("file");
    std::fs::write(&file, "x").unwrap();
    let r = rec.to_str().unwrap();
    let e = one_line_failure(&run(&["analyze", r, "--parquet", file.to_str().unwrap()]), 2);
    assert!(e.contains("--parquet") && e.contains("not a directory"), "{e}");
    let e = one_line_failure(&run(&["analyze", r, "--parquet", file.join("sub").to_str().unwrap()]), 2);
    assert!(e.contains("--parquet") && e.contains("file/sub") && e.contains("Not a directory"), "{e}");
    // Read-only (root writes anyway: then the files must be whole).
    use std::os::unix::fs::PermissionsExt as _;
    let ro = dir.path().join("ro");
    std::fs::create_dir(&ro).unwrap();
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
    let o = run(&["analyze", r, "--parquet", ro.to_str().unwrap()]);
    if o.status.success() {
        assert!(pq::read(&ro.join("profile.parquet")).rows > 0);
    } else {
        let e = one_line_failure(&o, 1);
        assert!(e.contains("profile.parquet"), "{e}");
        assert_eq!(std::fs::read_dir(&ro).unwrap().count(), 0);
    }
}

/// The HTML report: the survey header (the input, how the run was placed,
/// the chainage span), the verdict (edition and the source of its limits,
/// the reprofiling table, one zone row per zone, one block row per block,
/// the zone plot) as tables and figures, and a print stylesheet.
#[test]
fn the_report_has_the_survey_and_the_verdict_and_prints_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let rec = gappy_recording(dir.path());
    let report = dir.path().join("report");
    let r = rec.to_str().unwrap();
    let o = run(&["analyze", r, "--json", "--edition", "2012", "--block-m", "2", "--report", report.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let html = std::fs::read_to_string(report.join("report.html")).unwrap();
    let section = |id: &str| {
        let start = html.find(&format!("<section id=\"{id}\">")).unwrap_or_else(|| panic!("no section {id}"));
        let end = start + html[start..].find("</section>").unwrap();
        html[start..end].to_string()
    };
    let table_rows = |s: &str, class: &str| {
        let start = s.find(&format!("<table class=\"{class}\">")).unwrap_or_else(|| panic!("no table {class}: {s}"));
        let end = start + s[start..].find("</table>").unwrap();
        s[start..end].matches("<tr>").count() - 1
    };
    // The survey header.
    let survey = section("survey");
    assert!(survey.contains(r), "{survey}");
    assert!(survey.contains("run 1: position 0 at chainage 0+000.000"), "{survey}");
    assert_eq!(table_rows(&survey, "inputs"), 1);
    let x0 = v["lasers"].as_array().unwrap().iter().map(|l| l["x0_mm"].as_f64().unwrap()).fold(f64::INFINITY, f64::min);
    let span = format!("Chainage {} to", cms_host::analyze::chainage(x0));
    assert!(survey.contains(&span), "{span}: {survey}");
    // The verdict: edition and source, the tables with one row per band, zone, block.
    let verdict = section("verdict");
    let j = &v["verdict"];
    assert!(verdict.contains("EN 13231-3:2012"), "{verdict}");
    assert!(verdict.contains("trade documentation quotes the 2012 edition"), "{verdict}");
    assert!(verdict.contains("should be reprofiled"), "{verdict}");
    assert_eq!(table_rows(&verdict, "reprofiling"), 4);
    assert!(verdict.contains("not judged (no limit)"), "2012 has no limit for three bands: {verdict}");
    let zones = j["zones"].as_array().unwrap();
    assert!(!zones.is_empty());
    assert_eq!(table_rows(&verdict, "zones"), zones.len());
    for z in zones {
        assert!(verdict.contains(z["start_chainage"].as_str().unwrap()), "{z}");
    }
    assert_eq!(table_rows(&verdict, "blocks"), j["blocks"].as_array().unwrap().len());
    assert!(verdict.contains("<figure class=\"plot\"><svg"), "the zone plot inline");
    assert!(verdict.contains("|band displacement|"), "the 2012 criterion plotted");
    let svg = std::fs::read_to_string(report.join("zones.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("viewBox="), "scalable: {}", &svg[..100]);
    assert!(report.join("zones.png").exists());
    // Prints cleanly: a print stylesheet that breaks pages before sections,
    // scales the plots to the page and lets nothing overflow.
    let style = &html[html.find("<style>").unwrap()..html.find("</style>").unwrap()];
    let print = &style[style.find("@media print").expect("a print stylesheet")..];
    for rule in [
        "h2{break-before:page",
        "figure,img{max-width:100%",
        "svg{max-width:100%!important;max-height:165mm",
        "print-color-adjust:exact",
        "thead{display:table-header-group}",
    ] {
        assert!(print.contains(rule), "{rule}: {print}");
    }
    // Every plot is inside a figure, so that the print rules apply.
    assert_eq!(html.matches("<svg").count(), html.matches("<figure class=\"plot\"><svg").count());
    // The Markdown says the same.
    let md = std::fs::read_to_string(report.join("report.md")).unwrap();
    assert!(md.contains("## Verdict") && md.contains("zones.svg") && md.contains("EN 13231-3:2012"), "{md}");
}
