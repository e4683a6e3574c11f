//! Ultrasound in physical units: the standing wave of paper 002's Eq. 15 from pressure and
//! frequency, and a phased array of transducer elements rendering as the Bessel pattern its ring
//! sculpts (Graf's addition theorem), path for path; bad acoustic keys refused by name.

use crate::common;

use common::render;
use lightpath::config::{Task, load_text};
use lightpath::eikonal::Profile;
use lightpath::eikonal::acoustic::hankel;
use lightpath::rrte::RenderScene;

/// A clear water cylinder (radius 3, length 10) under a thin beam, with a flux window on the exit
/// face's axis: its power depends on how strongly the field focuses.
fn scene(profile: &str, modulation: &str) -> RenderScene {
    let text = format!(
        "[field]\nbounds = {{ kind = \"cylinder\", radius = 3.0, half_length = 5.0 }}\nn_out = 1.33\n[[field.profiles]]\n{profile}\n{modulation}\n[light]\nkind = \"beam\"\ncenter = [0.0, 0.0, -6.0]\ndirection = [0.0, 0.0, 1.0]\nradius = 0.4\n[[sensor]]\nkind = \"flux\"\nname = \"window\"\ncenter = [0.0, 0.0, 5.0]\nnormal = [0.0, 0.0, 1.0]\nsize = [0.2, 0.2]\n[render]\nstep = 0.05\n"
    );
    match load_text(&text) {
        Ok(Task::Render(t)) => t.scene,
        Ok(_) => panic!("not a render"),
        Err(e) => panic!("{e}"),
    }
}

fn refused(profile: &str, needles: &[&str]) {
    let text = format!(
        "[field]\nbounds = {{ kind = \"cylinder\", radius = 3.0, half_length = 5.0 }}\nn_out = 1.33\n[[field.profiles]]\n{profile}\n[light]\nkind = \"beam\"\ncenter = [0.0, 0.0, -6.0]\ndirection = [0.0, 0.0, 1.0]\n"
    );
    let Err(e) = load_text(&text) else {
        panic!("not refused: {profile}")
    };
    let e = e.to_string();
    for n in needles {
        assert!(e.contains(n), "{n:?} not in: {e}");
    }
}

/// 1 mm is the length unit; `k = 2` per mm in water at 1500 m/s.
const SOUND: f64 = 1500.0;
fn frequency(k: f64) -> f64 {
    k * SOUND / (std::f64::consts::TAU * 1e-3)
}

/// The paper's 813 kHz in water (1480 m/s) is `k_r = 3.45` per mm; the index amplitude is the
/// piezo-optic coefficient times the pressure, or the Lorentz–Lorenz coefficient of the density.
#[test]
fn the_standing_wave_in_physical_units_is_eq_15() {
    let physical = "kind = \"ultrasonic\"\nn0 = 1.33\nm = 2\npressure = 4e6\nfrequency = 813e3\nsound_speed = 1480.0\nlength_unit = \"mm\"\n";
    let field = |p: &str| scene(p, "").volume.field.profiles[0].clone();
    let Profile::Ultrasonic { n_max, k_r, m, .. } =
        field(&format!("{physical}piezo_optic = 1.5e-10"))
    else {
        panic!("ultrasonic")
    };
    assert!((k_r - 3.4515).abs() < 1e-4, "{k_r}");
    assert!((n_max - 6e-4).abs() < 1e-18 && m == 2, "{n_max}");
    // (n² − 1)(n² + 2)/(6 n ρ c²) for water at 1000 kg/m³
    let Profile::Ultrasonic { n_max, .. } = field(&format!("{physical}density = 1000.0")) else {
        panic!("ultrasonic")
    };
    let ll = (1.33f64.powi(2) - 1.0) * (1.33f64.powi(2) + 2.0)
        / (6.0 * 1.33 * 1000.0 * 1480.0f64.powi(2));
    assert!((n_max / (ll * 4e6) - 1.0).abs() < 1e-14, "{n_max}");
    // the mm and the m forms of the same wave
    let Profile::Ultrasonic { k_r: per_metre, .. } = field(
        &physical
            .replace("\"mm\"", "\"m\"")
            .replace("m = 2\n", "m = 2\npiezo_optic = 1e-10\n"),
    ) else {
        panic!("ultrasonic")
    };
    assert!((per_metre / k_r - 1e3).abs() < 1e-9);
}

/// A ring of 24 equal elements of radius 5 about a clear water lens (m = 0), phased so that its
/// pressure is `p_max J_0(k r) sin Ωt` inside (Graf: `N c H_0(kR) J_0(kr)`, aliased orders
/// `J_24(kr)` below 1e-13 here), renders photon for photon as the ultrasonic profile of the same
/// `n_max`: under the sinusoidal modulation (each photon's instant from the same random number)
/// and strobed. Its static field focuses differently: the test sees the instants.
#[test]
fn a_phased_ring_renders_as_its_bessel_pattern() {
    let (k, ring, count, n_max, piezo) = (2.0, 5.0, 24, 0.01, 1e-8);
    // each element's weight c = A/|H_0(k d)| at the reference distance d = ring; drive phase
    // π/2 − arg H_0(kR) turns N c e^{iψ} H_0(kR) into i p_max
    let h = hankel(0, k * ring);
    let amplitude = n_max / (piezo * count as f64);
    let phase = (std::f64::consts::FRAC_PI_2 - h.arg()).to_degrees();
    let elements: Vec<String> = (0..count)
        .map(|j| {
            let t = std::f64::consts::TAU * j as f64 / count as f64;
            format!(
                "{{ position = [{:.17e}, {:.17e}], amplitude = {amplitude:.17e}, phase_deg = {phase:.17e} }}",
                ring * t.cos(),
                ring * t.sin()
            )
        })
        .collect();
    let array = format!(
        "kind = \"phased_array\"\nn0 = 1.33\nfrequency = {:.17e}\nsound_speed = {SOUND}\nlength_unit = \"mm\"\npiezo_optic = {piezo}\nreference_distance = {ring}\nelements = [{}]\n",
        frequency(k),
        elements.join(", ")
    );
    let bessel = format!("kind = \"ultrasonic\"\nn0 = 1.33\nn_max = {n_max}\nk_r = {k}\nm = 0\n");
    for modulation in [
        "[modulation]\nkind = \"sinusoidal\"",
        "[modulation]\nkind = \"strobed\"\nphase_deg = 30.0",
    ] {
        let (sa, sb) = (scene(&array, modulation), scene(&bessel, modulation));
        let (a, est) = render(&sa, 4_000, 5);
        let (b, _) = render(&sb, 4_000, 5);
        let k = est.power(0);
        let (x, y) = (a.mean[k].re, b.mean[k].re);
        assert!(
            x > 0.0 && (x - y).abs() < 1e-6 * y,
            "{modulation}: array {x}, Eq. 15 {y}"
        );
    }
    // static, the array sits at its peak instant as the ultrasonic profile does
    let fixed = scene(&array, "");
    let (a, est) = render(&fixed, 4_000, 5);
    let (b, _) = render(&scene(&bessel, ""), 4_000, 5);
    let (c, _) = render(
        &scene(&bessel, "[modulation]\nkind = \"sinusoidal\""),
        4_000,
        5,
    );
    let k = est.power(0);
    assert!((a.mean[k].re - b.mean[k].re).abs() < 1e-6 * b.mean[k].re);
    assert!(
        (b.mean[k].re - c.mean[k].re).abs() > 5.0 * b.stderr[k].hypot(c.stderr[k]),
        "static {} vs modulated {}",
        b.mean[k].re,
        c.mean[k].re
    );
}

#[test]
fn bad_acoustic_keys_are_refused_by_name() {
    let array = |extra: &str, elements: &str| {
        format!(
            "kind = \"phased_array\"\nn0 = 1.33\nfrequency = 1e6\nsound_speed = 1500.0\nlength_unit = \"mm\"\nreference_distance = 5.0\n{extra}\nelements = [{elements}]\n"
        )
    };
    let one = "{ position = [5.0, 0.0], amplitude = 1e5 }";
    refused(
        &array(
            "piezo_optic = 1e-10",
            "{ position = [1.0, 2.0], amplitude = 1e5 }",
        ),
        &["elements[0].position = [1, 2]", "meets field.bounds"],
    );
    refused(
        &array("", one),
        &["piezo_optic", "density", "one of the two"],
    );
    refused(
        &array("piezo_optic = 1e-10\ndensity = 1000.0", one),
        &["piezo_optic", "density"],
    );
    refused(
        &array("piezo_optic = 1e-10", one).replace("\"mm\"", "\"inch\""),
        &["length_unit = \"inch\"", "\"mm\""],
    );
    refused(
        &array(
            "piezo_optic = 1e-10",
            "{ position = [5.0, 0.0], amplitude = -3.0 }",
        ),
        &["elements[0].amplitude = -3", ">= 0"],
    );
    refused(&array("piezo_optic = 1e-10", ""), &["elements holds 0"]);
    refused(
        &array("piezo_optic = 1e-10\nattenuation = -1.0", one),
        &["attenuation = -1"],
    );
    refused(
        "kind = \"ultrasonic\"\nn0 = 1.33\nm = 2\nn_max = 1e-3\nk_r = 3.0\nfrequency = 1e6",
        &["n_max and k_r", "not a mix"],
    );
    refused(
        "kind = \"ultrasonic\"\nn0 = 1.33\nm = 2\npressure = 1e6\nsound_speed = 1500.0\nlength_unit = \"mm\"\npiezo_optic = 1e-10",
        &["frequency: missing"],
    );
}
