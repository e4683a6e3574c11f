//! Triangle meshes read from files for signed-distance bounds: Wavefront OBJ (`v` and `f` lines;
//! polygons split into fans, `v/vt/vn` and negative indices accepted), STL (ASCII or binary) and
//! PLY (ASCII, binary little- or big-endian; `vertex` with `x`, `y`, `z`, and `face` with a
//! `vertex_indices` or `vertex_index` list). The format is told by the file's first bytes.

use crate::eikonal::mesh::Mesh;
use glam::DVec3;

/// Read the mesh in `path`; the error says what is wrong and where.
pub fn read_mesh(path: &str) -> Result<Mesh, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    let (vertices, triangles) = if bytes.starts_with(b"ply") {
        ply(&bytes)?
    } else if is_binary_stl(&bytes) {
        binary_stl(&bytes)?
    } else {
        let text = std::str::from_utf8(&bytes)
            .map_err(|_| "not a mesh: neither PLY, binary STL nor text (OBJ, ASCII STL)")?;
        if text.trim_start().starts_with("solid") {
            ascii_stl(text)?
        } else {
            obj(text)?
        }
    };
    if triangles.is_empty() {
        return Err("no triangles (an OBJ, STL or PLY mesh is read)".into());
    }
    Mesh::new(vertices, triangles)
}

type Triangles = (Vec<DVec3>, Vec<[usize; 3]>);

/// A polygon's fan of triangles.
fn fan(polygon: &[usize], triangles: &mut Vec<[usize; 3]>) {
    for k in 1..polygon.len().saturating_sub(1) {
        triangles.push([polygon[0], polygon[k], polygon[k + 1]]);
    }
}

fn obj(text: &str) -> Result<Triangles, String> {
    let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
    let mut polygon = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let at = |what: &str| format!("line {}: {what}: {line:?}", n + 1);
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let c: Vec<f64> = words
                    .take(3)
                    .map(|w| w.parse::<f64>())
                    .collect::<Result<_, _>>()
                    .map_err(|_| at("a vertex needs three numbers"))?;
                if c.len() < 3 {
                    return Err(at("a vertex needs three numbers"));
                }
                vertices.push(DVec3::new(c[0], c[1], c[2]));
            }
            Some("f") => {
                polygon.clear();
                for w in words {
                    let index: i64 = w
                        .split('/')
                        .next()
                        .and_then(|i| i.parse().ok())
                        .ok_or_else(|| at("a face's vertex is an index"))?;
                    // 1-based, or negative: counted back from the last vertex read
                    let k = if index > 0 {
                        index - 1
                    } else {
                        vertices.len() as i64 + index
                    };
                    if index == 0 || k < 0 || k >= vertices.len() as i64 {
                        return Err(at("a face names a vertex not read yet"));
                    }
                    polygon.push(k as usize);
                }
                if polygon.len() < 3 {
                    return Err(at("a face needs three vertices"));
                }
                fan(&polygon, &mut triangles);
            }
            _ => {}
        }
    }
    Ok((vertices, triangles))
}

/// Binary STL: an 80-byte header, a triangle count, and 50 bytes per triangle (a size that
/// matches exactly; ASCII files starting with "solid" seldom do).
fn is_binary_stl(bytes: &[u8]) -> bool {
    bytes.len() >= 84 && {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        bytes.len() == 84 + 50 * n
    }
}

fn binary_stl(bytes: &[u8]) -> Result<Triangles, String> {
    let n = (bytes.len() - 84) / 50;
    let float =
        |at: usize| f32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    let (mut vertices, mut triangles) = (Vec::with_capacity(3 * n), Vec::with_capacity(n));
    for t in 0..n {
        let base = 84 + 50 * t + 12; // past the facet normal
        for c in 0..3 {
            let at = base + 12 * c;
            vertices.push(DVec3::new(
                float(at) as f64,
                float(at + 4) as f64,
                float(at + 8) as f64,
            ));
        }
        triangles.push([3 * t, 3 * t + 1, 3 * t + 2]);
    }
    Ok((vertices, triangles))
}

fn ascii_stl(text: &str) -> Result<Triangles, String> {
    let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
    let mut polygon = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("vertex") => {
                let c: Vec<f64> = words.filter_map(|w| w.parse().ok()).collect();
                if c.len() != 3 {
                    return Err(format!(
                        "line {}: a vertex needs three numbers: {line:?}",
                        n + 1
                    ));
                }
                polygon.push(vertices.len());
                vertices.push(DVec3::new(c[0], c[1], c[2]));
            }
            Some("endloop") => {
                fan(&polygon, &mut triangles);
                polygon.clear();
            }
            _ => {}
        }
    }
    Ok((vertices, triangles))
}

/// A PLY property's scalar type.
#[derive(Clone, Copy)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// The value at the start of `b`, in `little` or big endian order.
    fn read(self, b: &[u8], little: bool) -> f64 {
        let mut raw = [0u8; 8];
        let n = self.size();
        raw[..n].copy_from_slice(&b[..n]);
        if !little {
            raw[..n].reverse();
        }
        match self {
            Scalar::I8 => raw[0] as i8 as f64,
            Scalar::U8 => raw[0] as f64,
            Scalar::I16 => i16::from_le_bytes([raw[0], raw[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([raw[0], raw[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(raw),
        }
    }
}

/// A PLY property: a scalar, or a list (its count's type and its items').
struct Property {
    name: String,
    kind: Scalar,
    list: Option<Scalar>,
}

struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

fn ply(bytes: &[u8]) -> Result<Triangles, String> {
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or("PLY: no end_header")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "PLY: the header is not text")?;
    let mut body = &bytes[end + 10..];
    // the line break after end_header
    while let Some((&b, rest)) = body.split_first() {
        body = rest;
        if b == b'\n' {
            break;
        }
    }
    let mut format = "";
    let mut elements: Vec<Element> = Vec::new();
    for line in header.lines().skip(1) {
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = || format!("PLY: cannot read the header line {line:?}");
        match words.first().copied() {
            Some("format") => format = words.get(1).copied().unwrap_or(""),
            Some("element") => elements.push(Element {
                name: words.get(1).ok_or_else(bad)?.to_string(),
                count: words.get(2).and_then(|c| c.parse().ok()).ok_or_else(bad)?,
                properties: Vec::new(),
            }),
            Some("property") => {
                let element = elements.last_mut().ok_or_else(bad)?;
                let property = if words.get(1) == Some(&"list") {
                    Property {
                        name: words.get(4).ok_or_else(bad)?.to_string(),
                        kind: words
                            .get(3)
                            .and_then(|w| Scalar::parse(w))
                            .ok_or_else(bad)?,
                        list: Some(
                            words
                                .get(2)
                                .and_then(|w| Scalar::parse(w))
                                .ok_or_else(bad)?,
                        ),
                    }
                } else {
                    Property {
                        name: words.get(2).ok_or_else(bad)?.to_string(),
                        kind: words
                            .get(1)
                            .and_then(|w| Scalar::parse(w))
                            .ok_or_else(bad)?,
                        list: None,
                    }
                };
                element.properties.push(property);
            }
            _ => {}
        }
    }
    let little = match format {
        "ascii" => None,
        "binary_little_endian" => Some(true),
        "binary_big_endian" => Some(false),
        other => return Err(format!("PLY: unknown format {other:?}")),
    };
    let mut values = Values {
        body,
        little,
        text: None,
    };
    if little.is_none() {
        values.text = Some(
            std::str::from_utf8(body)
                .map_err(|_| "PLY: the ASCII body is not text")?
                .split_whitespace(),
        );
    }
    let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
    let mut polygon = Vec::new();
    for e in &elements {
        let axis = |name: &str| e.properties.iter().position(|p| p.name == name);
        let xyz = [axis("x"), axis("y"), axis("z")];
        if e.name == "vertex" && xyz.iter().any(Option::is_none) {
            return Err("PLY: the vertex element has no x, y and z".into());
        }
        for _ in 0..e.count {
            let mut point = [0.0; 3];
            for (k, p) in e.properties.iter().enumerate() {
                match p.list {
                    None => {
                        let v = values.next(p.kind)?;
                        if let Some(a) = xyz.iter().position(|&i| i == Some(k)) {
                            point[a] = v;
                        }
                    }
                    Some(count_kind) => {
                        let count = values.next(count_kind)? as usize;
                        polygon.clear();
                        for _ in 0..count {
                            polygon.push(values.next(p.kind)? as usize);
                        }
                        if e.name == "face"
                            && (p.name == "vertex_indices" || p.name == "vertex_index")
                        {
                            fan(&polygon, &mut triangles);
                        }
                    }
                }
            }
            if e.name == "vertex" {
                vertices.push(DVec3::from_array(point));
            }
        }
    }
    Ok((vertices, triangles))
}

/// The values of a PLY body in order.
struct Values<'a> {
    body: &'a [u8],
    little: Option<bool>,
    text: Option<std::str::SplitWhitespace<'a>>,
}

impl Values<'_> {
    fn next(&mut self, kind: Scalar) -> Result<f64, String> {
        if let Some(words) = &mut self.text {
            return words
                .next()
                .and_then(|w| w.parse().ok())
                .ok_or_else(|| "PLY: the body ends early or holds a non-number".to_string());
        }
        let n = kind.size();
        if self.body.len() < n {
            return Err("PLY: the body ends early".into());
        }
        let v = kind.read(self.body, self.little.unwrap_or(true));
        self.body = &self.body[n..];
        Ok(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tetrahedron, faces outwards, written in each format: they read the same.
    #[test]
    fn every_format_reads_the_same_mesh() {
        let v: [[f64; 3]; 4] = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ];
        let f = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let dir = std::env::temp_dir().join(format!("lightpath-mesh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut files = Vec::new();
        // OBJ, with a quad split in two and negative indices
        let mut obj = String::from("# tetrahedron\n");
        for p in v {
            obj += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        }
        obj += "f 1/1/1 3 2\nf -4 -3 -1\nf 1 4 3\nf 2 3 4\n";
        files.push(("t.obj", obj.into_bytes()));
        // ASCII and binary STL
        let mut stl = String::from("solid t\n");
        let mut bin = vec![0u8; 80];
        bin.extend((f.len() as u32).to_le_bytes());
        for t in f {
            stl += "facet normal 0 0 0\nouter loop\n";
            bin.extend([0u8; 12]);
            for k in t {
                stl += &format!("vertex {} {} {}\n", v[k][0], v[k][1], v[k][2]);
                for c in v[k] {
                    bin.extend((c as f32).to_le_bytes());
                }
            }
            stl += "endloop\nendfacet\n";
            bin.extend([0u8; 2]);
        }
        stl += "endsolid t\n";
        files.push(("a.stl", stl.into_bytes()));
        files.push(("b.stl", bin));
        // PLY: ASCII, and binary both ways
        let head = |format: &str| {
            format!(
                "ply\nformat {format} 1.0\ncomment t\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\nproperty uchar red\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
            )
        };
        let mut ascii = head("ascii");
        for p in v {
            ascii += &format!("{} {} {} 255\n", p[0], p[1], p[2]);
        }
        for t in f {
            ascii += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
        }
        files.push(("a.ply", ascii.into_bytes()));
        for (name, little) in [("l.ply", true), ("b.ply", false)] {
            let mut b = head(if little {
                "binary_little_endian"
            } else {
                "binary_big_endian"
            })
            .into_bytes();
            for p in v {
                for c in p {
                    b.extend(if little {
                        c.to_le_bytes()
                    } else {
                        c.to_be_bytes()
                    });
                }
                b.push(255);
            }
            for t in f {
                b.push(3);
                for k in t {
                    b.extend(if little {
                        (k as i32).to_le_bytes()
                    } else {
                        (k as i32).to_be_bytes()
                    });
                }
            }
            files.push((name, b));
        }
        let inside = DVec3::splat(0.1);
        for (name, bytes) in files {
            let path = dir.join(name);
            std::fs::write(&path, bytes).unwrap();
            let mesh = read_mesh(path.to_str().unwrap()).unwrap();
            assert_eq!(mesh.triangles.len(), 4, "{name}");
            let w = mesh.winding_number(inside);
            assert!((w - 1.0).abs() < 1e-9, "{name}: w = {w}");
            assert!((mesh.signed_distance(inside) + 0.1).abs() < 1e-7, "{name}");
        }
        for (name, text, wanted) in [
            ("bad.obj", "v 0 0 0\nf 1 2 3\n", "line 2"),
            ("empty.obj", "v 0 0 0\n", "no triangles"),
            (
                "bad.ply",
                "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n",
                "x, y and z",
            ),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, text).unwrap();
            let e = read_mesh(path.to_str().unwrap()).unwrap_err();
            assert!(e.contains(wanted), "{name}: {e}");
        }
        let _ = std::fs::remove_dir_all(dir);
    }
}
