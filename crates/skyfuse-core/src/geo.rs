//! WGS-84 geodetic ↔ ECEF ↔ local ENU, exactly (no flat-earth shortcut).

use nalgebra::{Matrix3, Vector3};

/// WGS-84 semi-major axis, m.
pub const WGS84_A: f64 = 6_378_137.0;
/// WGS-84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
const E2: f64 = WGS84_F * (2.0 - WGS84_F);

/// Geodetic (degrees, degrees, metres above the ellipsoid) → ECEF metres.
pub fn geodetic_to_ecef(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Vector3<f64> {
    let (lat, lon) = (lat_deg.to_radians(), lon_deg.to_radians());
    let (sl, cl) = lat.sin_cos();
    let n = WGS84_A / (1.0 - E2 * sl * sl).sqrt();
    Vector3::new(
        (n + alt_m) * cl * lon.cos(),
        (n + alt_m) * cl * lon.sin(),
        (n * (1.0 - E2) + alt_m) * sl,
    )
}

/// ECEF → geodetic (degrees, degrees, metres), iterated to sub-millimetre.
pub fn ecef_to_geodetic(p: Vector3<f64>) -> (f64, f64, f64) {
    let lon = p.y.atan2(p.x);
    let r = (p.x * p.x + p.y * p.y).sqrt();
    let mut lat = p.z.atan2(r * (1.0 - E2));
    let mut alt = 0.0;
    for _ in 0..10 {
        let sl = lat.sin();
        let n = WGS84_A / (1.0 - E2 * sl * sl).sqrt();
        alt = r / lat.cos() - n;
        let next = p.z.atan2(r * (1.0 - E2 * n / (n + alt)));
        let done = (next - lat).abs() < 1e-13;
        lat = next;
        if done {
            break;
        }
    }
    (lat.to_degrees(), lon.to_degrees(), alt)
}

/// A local East-North-Up tangent plane anchored at an origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalEnu {
    pub origin_lat_deg: f64,
    pub origin_lon_deg: f64,
    pub origin_alt_m: f64,
    origin_ecef: Vector3<f64>,
    /// Rows: east, north, up unit vectors in ECEF.
    ecef_to_enu: Matrix3<f64>,
}

impl LocalEnu {
    pub fn new(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Self {
        let (lat, lon) = (lat_deg.to_radians(), lon_deg.to_radians());
        let (sl, cl) = lat.sin_cos();
        let (so, co) = lon.sin_cos();
        let ecef_to_enu = Matrix3::new(
            -so,
            co,
            0.0, //
            -sl * co,
            -sl * so,
            cl, //
            cl * co,
            cl * so,
            sl,
        );
        Self {
            origin_lat_deg: lat_deg,
            origin_lon_deg: lon_deg,
            origin_alt_m: alt_m,
            origin_ecef: geodetic_to_ecef(lat_deg, lon_deg, alt_m),
            ecef_to_enu,
        }
    }

    pub fn to_enu(&self, lat_deg: f64, lon_deg: f64, alt_m: f64) -> Vector3<f64> {
        self.ecef_to_enu * (geodetic_to_ecef(lat_deg, lon_deg, alt_m) - self.origin_ecef)
    }

    pub fn to_geodetic(&self, enu: Vector3<f64>) -> (f64, f64, f64) {
        ecef_to_geodetic(self.origin_ecef + self.ecef_to_enu.transpose() * enu)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ecef_of_known_points() {
        // Equator / prime meridian: x = a.
        let p = geodetic_to_ecef(0.0, 0.0, 0.0);
        assert!((p - Vector3::new(WGS84_A, 0.0, 0.0)).norm() < 1e-6);
        // North pole: z = b = a(1-f).
        let p = geodetic_to_ecef(90.0, 0.0, 0.0);
        assert!((p.z - 6_356_752.314_245).abs() < 1e-3, "{}", p.z);
        // Zürich (PX4 SITL home); reference from PROJ, an independent implementation:
        // pyproj Transformer EPSG:4979 → EPSG:4978 of (8.545594, 47.397742, 488.0).
        let p = geodetic_to_ecef(47.397742, 8.545594, 488.0);
        let expected = Vector3::new(4_277_551.169, 642_764.676, 4_672_168.686);
        assert!((p - expected).norm() < 2e-3, "{p} vs {expected}");
    }

    #[test]
    fn enu_round_trip_and_axes() {
        let enu = LocalEnu::new(47.397742, 8.545594, 488.0);
        let (lat, lon, alt) = enu.to_geodetic(Vector3::new(100.0, -250.0, 30.0));
        let back = enu.to_enu(lat, lon, alt);
        assert!(
            (back - Vector3::new(100.0, -250.0, 30.0)).norm() < 1e-6,
            "{back}"
        );
        // One arc-second of latitude north is ~30.87 m north at this latitude.
        let n = enu.to_enu(47.397742 + 1.0 / 3600.0, 8.545594, 488.0);
        assert!(
            n.x.abs() < 1e-3 && (n.y - 30.87).abs() < 0.05 && n.z.abs() < 0.01,
            "{n}"
        );
        // Going east lowers "up" by the earth's curvature: 1 km east → ~7.8 cm down.
        let (lat, lon, alt) = enu.to_geodetic(Vector3::new(1000.0, 0.0, 0.0));
        let flat = LocalEnu::new(lat, lon, alt).to_enu(47.397742, 8.545594, 488.0);
        assert!((flat.norm() - 1000.0).abs() < 1e-3);
        let up = enu.to_enu(lat, lon, 488.0).z;
        assert!((up + 0.0785).abs() < 0.002, "{up}");
    }
}
