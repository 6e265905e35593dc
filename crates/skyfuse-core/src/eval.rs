//! Trajectory evaluation as evo computes it (MichaelGrupp/evo 1.38: `core/sync.py`,
//! `core/geometry.py`, `core/trajectory.py`, `core/metrics.py`, `main_ape.py`), so that
//! [`evo_ape`] reproduces `evo_ape tum ref.tum est.tum [-a] [-s] [--align_origin]
//! [--t_max_diff D] [--t_offset O]` for the APE translation part, and TUM files
//! written here can be handed to evo itself.
//!
//! The steps follow evo's order and conventions: associate the poses by nearest
//! timestamp ([`associate`]), optionally align the estimate to the reference (Umeyama
//! SE(3)/Sim(3) on positions, or the first poses for `align_origin`), then take the
//! statistics of ‖p_est − p_ref‖ ([`ApeStats`]; `std` is the population deviation,
//! `median` averages the two middle values, as numpy does).

use nalgebra::{
    Isometry3, Matrix3, Point3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3,
};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Poses at times: `t` in seconds, `p` positions, `q` orientations (body → world).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Trajectory {
    pub t: Vec<f64>,
    pub p: Vec<Vector3<f64>>,
    pub q: Vec<UnitQuaternion<f64>>,
}

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("{}:{line}: {found} fields, a TUM line has 8 (t x y z qx qy qz qw)", file.display())]
    TumFields {
        file: PathBuf,
        line: usize,
        found: usize,
    },
    #[error("{}:{line}:{column}: {text:?} is not a finite number", file.display())]
    TumNumber {
        file: PathBuf,
        line: usize,
        column: usize,
        text: String,
    },
    #[error("{}:{line}:5: zero quaternion", file.display())]
    TumQuaternion { file: PathBuf, line: usize },
    #[error("{}: no poses", file.display())]
    TumEmpty { file: PathBuf },
    #[error("trajectory has {t} stamps, {p} positions and {q} orientations")]
    Ragged { t: usize, p: usize, q: usize },
    #[error("reference has {reference} poses and estimate {estimate}: associate them first")]
    LengthMismatch { reference: usize, estimate: usize },
    #[error("empty trajectory")]
    Empty,
    #[error(
        "no matching timestamps with max. time diff {max_diff_s} s and time offset {offset_s} s"
    )]
    NoMatches { max_diff_s: f64, offset_s: f64 },
    #[error("degenerate covariance rank, Umeyama alignment is not possible")]
    Degenerate,
    #[error("align and align_origin can't be used together")]
    AlignAndOrigin,
}

/// Appends `v` with `digits` decimals, exactly as `format!("{v:.digits$}")` does (the
/// exact binary value rounded half to even, a negative zero signed) but from integers:
/// formatting floats was a tenth of a replay that writes a long log's tracks.
pub fn push_fixed(out: &mut Vec<u8>, v: f64, digits: u32) {
    // Beyond these the general formatter (its cases are rare: not a pose's numbers).
    if !v.is_finite() || v.abs() >= 1e15 || digits > 9 {
        out.extend_from_slice(format!("{v:.*}", digits as usize).as_bytes());
        return;
    }
    let bits = v.to_bits();
    let exponent = ((bits >> 52) & 0x7ff) as i32;
    let fraction = bits & ((1 << 52) - 1);
    // v = mantissa · 2^power, exactly.
    let (mantissa, power) = if exponent == 0 {
        (fraction, -1074)
    } else {
        (fraction | (1 << 52), exponent - 1075)
    };
    let scale = 10u128.pow(digits);
    // Below 1e15 (< 2^50) the power is negative: v·10^digits = n / 2^shift.
    let n = u128::from(mantissa) * scale;
    let shift = power.unsigned_abs();
    let scaled = if power >= 0 {
        n << shift
    } else if shift >= 128 {
        0
    } else {
        let (q, r, half) = (n >> shift, n & ((1 << shift) - 1), 1u128 << (shift - 1));
        if r > half || (r == half && q & 1 == 1) {
            q + 1
        } else {
            q
        }
    };
    if v.is_sign_negative() {
        out.push(b'-');
    }
    // Both parts fit 64 bits (below 1e15, and below 10^9); the division in 64 bits
    // where the scaled value fits (a pose's numbers: below 1.8e10 at 9 digits), as a
    // 128-bit one is a call.
    let (int, frac) = match u64::try_from(scaled) {
        Ok(n) => (n / scale as u64, n % scale as u64),
        Err(_) => ((scaled / scale) as u64, (scaled % scale) as u64),
    };
    push_decimal(out, int, 1);
    if digits > 0 {
        out.push(b'.');
        push_decimal(out, frac, digits as usize);
    }
}

/// Appends `n` in decimal, zero-padded to `width` (at most 20) digits: what `write!`
/// of `{n:0width$}` gives, without the formatter's machinery (a third of `push_fixed`).
fn push_decimal(out: &mut Vec<u8>, mut n: u64, width: usize) {
    let mut buf = [b'0'; 20];
    let mut start = buf.len();
    loop {
        start -= 1;
        buf[start] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    let start = start.min(buf.len() - width.min(buf.len()));
    out.extend_from_slice(&buf[start..]);
}

impl Trajectory {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn push(&mut self, t: f64, p: Vector3<f64>, q: UnitQuaternion<f64>) {
        self.t.push(t);
        self.p.push(p);
        self.q.push(q);
    }

    pub fn len(&self) -> usize {
        self.t.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    fn check(&self) -> Result<(), EvalError> {
        let (t, p, q) = (self.t.len(), self.p.len(), self.q.len());
        if t == p && p == q {
            Ok(())
        } else {
            Err(EvalError::Ragged { t, p, q })
        }
    }

    /// The poses at `ids`, in that order (evo's `reduce_to_ids`).
    pub fn select(&self, ids: &[usize]) -> Trajectory {
        Trajectory {
            t: ids.iter().map(|&i| self.t[i]).collect(),
            p: ids.iter().map(|&i| self.p[i]).collect(),
            q: ids.iter().map(|&i| self.q[i]).collect(),
        }
    }

    /// TUM text, `t x y z qx qy qz qw` per line, with fixed decimals (6 for t, 9 for the
    /// rest) so the same trajectory always gives the same bytes.
    pub fn to_tum(&self) -> Result<String, EvalError> {
        self.check()?;
        // Bytes, made a string once: ASCII throughout, so that never copies.
        let mut s = Vec::with_capacity(self.len() * 96);
        for ((t, p), q) in self.t.iter().zip(&self.p).zip(&self.q) {
            push_fixed(&mut s, *t, 6);
            for v in [p.x, p.y, p.z, q.i, q.j, q.k, q.w] {
                s.push(b' ');
                push_fixed(&mut s, v, 9);
            }
            s.push(b'\n');
        }
        Ok(String::from_utf8(s)
            .unwrap_or_else(|e| String::from_utf8_lossy(e.as_bytes()).into_owned()))
    }

    pub fn write_tum(&self, path: &Path) -> Result<(), EvalError> {
        std::fs::write(path, self.to_tum()?).map_err(|source| EvalError::Io {
            file: path.to_path_buf(),
            source,
        })
    }

    pub fn read_tum(path: &Path) -> Result<Self, EvalError> {
        let text = std::fs::read_to_string(path).map_err(|source| EvalError::Io {
            file: path.to_path_buf(),
            source,
        })?;
        Self::parse_tum(&text, path)
    }

    /// Parses TUM text; `file` only names the source in errors. Lines starting with `#`
    /// and blank lines are skipped; fields may be separated by any whitespace (evo wants
    /// single spaces; anything evo reads, this reads).
    pub fn parse_tum(text: &str, file: &Path) -> Result<Self, EvalError> {
        let mut traj = Trajectory::new();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split_whitespace().collect();
            if fields.len() != 8 {
                return Err(EvalError::TumFields {
                    file: file.to_path_buf(),
                    line: i + 1,
                    found: fields.len(),
                });
            }
            let mut v = [0.0; 8];
            for (k, (f, out)) in fields.iter().zip(v.iter_mut()).enumerate() {
                *out = f
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| EvalError::TumNumber {
                        file: file.to_path_buf(),
                        line: i + 1,
                        column: k + 1,
                        text: f.to_string(),
                    })?;
            }
            let q = Quaternion::new(v[7], v[4], v[5], v[6]);
            if q.norm() < 1e-12 {
                return Err(EvalError::TumQuaternion {
                    file: file.to_path_buf(),
                    line: i + 1,
                });
            }
            traj.push(
                v[0],
                Vector3::new(v[1], v[2], v[3]),
                UnitQuaternion::from_quaternion(q),
            );
        }
        if traj.is_empty() {
            return Err(EvalError::TumEmpty {
                file: file.to_path_buf(),
            });
        }
        Ok(traj)
    }

    /// Left-multiplies every pose by `iso` (evo's `transform`).
    pub fn transform(&mut self, iso: &Isometry3<f64>) {
        for p in &mut self.p {
            // A Point3, not a Vector3: nalgebra does not translate vectors.
            *p = iso.transform_point(&Point3::from(*p)).coords;
        }
        for q in &mut self.q {
            *q = iso.rotation * *q;
        }
    }

    /// Scales the positions (evo's `scale`).
    pub fn scale(&mut self, s: f64) {
        for p in &mut self.p {
            *p *= s;
        }
    }

    /// evo's `align`: Umeyama on the positions, estimate (self) onto `reference`, which
    /// must be associated already. `correct_only_scale` applies the scale alone.
    pub fn align(
        &mut self,
        reference: &Trajectory,
        correct_scale: bool,
        correct_only_scale: bool,
    ) -> Result<Sim3, EvalError> {
        let sim = umeyama(&self.p, &reference.p, correct_scale || correct_only_scale)?;
        if correct_scale || correct_only_scale {
            self.scale(sim.scale);
        }
        if !correct_only_scale {
            self.transform(&sim.isometry());
        }
        Ok(sim)
    }

    /// evo's `align_origin`: moves the whole trajectory so its first pose is the
    /// reference's first pose; returns the transformation used.
    pub fn align_origin(&mut self, reference: &Trajectory) -> Result<Isometry3<f64>, EvalError> {
        self.check()?;
        reference.check()?;
        if self.is_empty() || reference.is_empty() {
            return Err(EvalError::Empty);
        }
        let pose = |tr: &Trajectory| Isometry3::from_parts(Translation3::from(tr.p[0]), tr.q[0]);
        let to_ref = pose(reference) * pose(self).inverse();
        self.transform(&to_ref);
        Ok(to_ref)
    }
}

/// evo's `matching_time_indices`: for each stamp of `stamps_1`, the nearest stamp of
/// `stamps_2 + offset_2` within `max_diff` (ties go to the earlier one). Not one-to-one
/// on the second side: two stamps of the first may pick the same one, as in evo.
/// Unsorted `stamps_2` falls back to a linear search, as in evo.
pub fn matching_time_indices(
    stamps_1: &[f64],
    stamps_2: &[f64],
    max_diff: f64,
    offset_2: f64,
) -> (Vec<usize>, Vec<usize>) {
    let s2: Vec<f64> = stamps_2.iter().map(|t| t + offset_2).collect();
    let (mut m1, mut m2) = (Vec::new(), Vec::new());
    let (Some(&first), Some(&last)) = (s2.first(), s2.last()) else {
        return (m1, m2);
    };
    if !s2.windows(2).all(|w| w[1] - w[0] >= 0.0) {
        for (i1, &t1) in stamps_1.iter().enumerate() {
            // numpy's argmin: the first of equal minima.
            let mut best: Option<(usize, f64)> = None;
            for (i2, &t2) in s2.iter().enumerate() {
                let d = (t2 - t1).abs();
                if best.is_none_or(|(_, b)| d < b) {
                    best = Some((i2, d));
                }
            }
            if let Some((i2, _)) = best.filter(|&(_, d)| d <= max_diff) {
                m1.push(i1);
                m2.push(i2);
            }
        }
        return (m1, m2);
    }
    for (i1, &t1) in stamps_1.iter().enumerate() {
        if t1 < first - max_diff || t1 > last + max_diff {
            continue;
        }
        // np.searchsorted(side="right"), clamped to the last index.
        let i2 = s2.partition_point(|&t| t <= t1).min(s2.len() - 1);
        let diff_ub = s2[i2] - t1;
        let diff_lb = if i2 > 0 {
            t1 - s2[i2 - 1]
        } else {
            f64::INFINITY
        };
        let best = if diff_ub <= max_diff && diff_ub < diff_lb {
            i2
        } else if diff_lb <= max_diff && diff_lb <= diff_ub {
            i2 - 1
        } else {
            continue;
        };
        m1.push(i1);
        m2.push(best);
    }
    (m1, m2)
}

/// evo's `associate_trajectories` (nearest-time method): matches from the trajectory
/// with fewer poses (the estimate on a tie) so none of its poses are lost, and returns
/// both reduced to the matches, in argument order, each keeping its own timestamps.
/// `offset_s` is added to `b`'s stamps for the matching only.
pub fn associate(
    a: &Trajectory,
    b: &Trajectory,
    max_diff_s: f64,
    offset_s: f64,
) -> Result<(Trajectory, Trajectory), EvalError> {
    a.check()?;
    b.check()?;
    let second_longer = b.len() > a.len();
    let (short, long) = if second_longer { (a, b) } else { (b, a) };
    let offset = if second_longer { offset_s } else { -offset_s };
    let (ids_short, ids_long) = matching_time_indices(&short.t, &long.t, max_diff_s, offset);
    if ids_short.is_empty() {
        return Err(EvalError::NoMatches {
            max_diff_s,
            offset_s,
        });
    }
    let (short, long) = (short.select(&ids_short), long.select(&ids_long));
    Ok(if second_longer {
        (short, long)
    } else {
        (long, short)
    })
}

/// A similarity transform y = scale · rotation · x + translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
    pub scale: f64,
}

impl Sim3 {
    pub fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * x) + self.translation
    }

    /// The rigid part (rotation and translation, without the scale).
    pub fn isometry(&self) -> Isometry3<f64> {
        let r = Rotation3::from_matrix_unchecked(self.rotation);
        Isometry3::from_parts(
            Translation3::from(self.translation),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }
}

/// Umeyama's least-squares similarity (IEEE PAMI 1991) taking points `x` onto `y`, as
/// evo's `umeyama_alignment`; scale 1 unless `with_scale`.
pub fn umeyama(
    x: &[Vector3<f64>],
    y: &[Vector3<f64>],
    with_scale: bool,
) -> Result<Sim3, EvalError> {
    if x.len() != y.len() {
        return Err(EvalError::LengthMismatch {
            reference: y.len(),
            estimate: x.len(),
        });
    }
    if x.is_empty() {
        return Err(EvalError::Empty);
    }
    let n = x.len() as f64;
    let mean = |v: &[Vector3<f64>]| v.iter().sum::<Vector3<f64>>() / n;
    let (mean_x, mean_y) = (mean(x), mean(y));
    let sigma_x = x.iter().map(|p| (p - mean_x).norm_squared()).sum::<f64>() / n;
    let cov = x
        .iter()
        .zip(y)
        .map(|(px, py)| (py - mean_y) * (px - mean_x).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    // nalgebra's SVD::new sorts the singular values in decreasing order, like LAPACK,
    // so the sign fix below lands on the smallest one as in evo.
    let svd = cov.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(EvalError::Degenerate);
    };
    let d = svd.singular_values;
    if d.iter().filter(|&&s| s > f64::EPSILON).count() < 2 {
        return Err(EvalError::Degenerate);
    }
    let mut s = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        // Keep a proper rotation (Kabsch).
        s[(2, 2)] = -1.0;
    }
    let rotation = u * s * v_t;
    let scale = if with_scale {
        (d[0] + d[1] + s[(2, 2)] * d[2]) / sigma_x
    } else {
        1.0
    };
    Ok(Sim3 {
        rotation,
        translation: mean_y - scale * (rotation * mean_x),
        scale,
    })
}

/// Statistics of the APE translation part, evo's names and definitions.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ApeStats {
    pub rmse: f64,
    pub mean: f64,
    pub median: f64,
    /// Population standard deviation (numpy's default).
    pub std: f64,
    pub min: f64,
    pub max: f64,
    /// Sum of squared errors.
    pub sse: f64,
    /// Pose pairs compared.
    pub n: usize,
}

impl ApeStats {
    /// `None` for no errors.
    pub fn from_errors(errors: &[f64]) -> Option<ApeStats> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n;
        let var = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let mid = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 {
            sorted[mid]
        } else {
            (sorted[mid - 1] + sorted[mid]) / 2.0
        };
        Some(ApeStats {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[sorted.len() - 1],
            sse,
            n: errors.len(),
        })
    }
}

/// ‖p_est − p_ref‖ per pose pair of two associated trajectories.
pub fn translation_errors(
    reference: &Trajectory,
    estimate: &Trajectory,
) -> Result<Vec<f64>, EvalError> {
    if reference.p.len() != estimate.p.len() {
        return Err(EvalError::LengthMismatch {
            reference: reference.p.len(),
            estimate: estimate.p.len(),
        });
    }
    Ok(reference
        .p
        .iter()
        .zip(&estimate.p)
        .map(|(r, e)| (e - r).norm())
        .collect())
}

/// evo's APE translation part (`evo.main_ape.ape`) on two associated trajectories:
/// `align` is Umeyama SE(3), with `correct_scale` Sim(3); `correct_scale` alone only
/// corrects the scale (evo's `-s` without `-a`).
pub fn ape_translation(
    reference: &Trajectory,
    estimate: &Trajectory,
    align: bool,
    correct_scale: bool,
) -> Result<ApeStats, EvalError> {
    ape(reference, estimate, align, correct_scale, false)
}

fn ape(
    reference: &Trajectory,
    estimate: &Trajectory,
    align: bool,
    correct_scale: bool,
    align_origin: bool,
) -> Result<ApeStats, EvalError> {
    if align && align_origin {
        return Err(EvalError::AlignAndOrigin);
    }
    reference.check()?;
    estimate.check()?;
    let mut est = estimate.clone();
    if align || correct_scale {
        est.align(reference, correct_scale, correct_scale && !align)?;
    }
    if align_origin {
        est.align_origin(reference)?;
    }
    ApeStats::from_errors(&translation_errors(reference, &est)?).ok_or(EvalError::Empty)
}

/// `evo_ape tum` options. The defaults are evo's: no alignment, 10 ms, no offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApeOptions {
    /// `-a`
    pub align: bool,
    /// `-s`
    pub correct_scale: bool,
    /// `--align_origin`
    pub align_origin: bool,
    /// `--t_max_diff`, s.
    pub max_diff_s: f64,
    /// `--t_offset`, s, added to the estimate's stamps for association.
    pub offset_s: f64,
}

impl Default for ApeOptions {
    fn default() -> Self {
        Self {
            align: false,
            correct_scale: false,
            align_origin: false,
            max_diff_s: 0.01,
            offset_s: 0.0,
        }
    }
}

/// What `evo_ape tum` reports for the translation part: associate, align, compare.
pub fn evo_ape(
    reference: &Trajectory,
    estimate: &Trajectory,
    opts: &ApeOptions,
) -> Result<ApeStats, EvalError> {
    if opts.align && opts.align_origin {
        return Err(EvalError::AlignAndOrigin);
    }
    let (r, e) = associate(reference, estimate, opts.max_diff_s, opts.offset_s)?;
    ape(&r, &e, opts.align, opts.correct_scale, opts.align_origin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_formatting_is_the_standard_formatters_to_the_byte() {
        let mut cases: Vec<f64> = vec![
            0.0,
            -0.0,
            0.5,
            2.5,
            -0.25,
            1e-20,
            -1e-20,
            0.000_000_000_5,
            0.000_000_001_5,
            1.0005,
            123_456.789_012_345_6,
            1e15,
            9.999e14,
            -9.999e14,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MIN_POSITIVE,
            5e-324,
            1.0 / 3.0,
        ];
        // Ties at every decimal place: k / 2^n, exactly halfway more often than not.
        for n in 1..40 {
            for k in [1_u64, 3, 5, 7, 1_000_001, 123_456_789] {
                cases.push(k as f64 / (1_u64 << n) as f64);
                cases.push(-(k as f64) / (1_u64 << n) as f64);
            }
        }
        // Random bit patterns over the magnitudes a pose and a time have (and beyond).
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        for _ in 0..300_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let exponent = 1023 - 60 + (x >> 52) % 115;
            cases.push(f64::from_bits(
                (x & 0x800f_ffff_ffff_ffff) | (exponent << 52),
            ));
        }
        for v in cases {
            for digits in [0, 1, 6, 9] {
                let mut s = Vec::new();
                push_fixed(&mut s, v, digits);
                assert_eq!(
                    String::from_utf8_lossy(&s),
                    format!("{v:.*}", digits as usize),
                    "{v:e} {digits}"
                );
            }
        }
    }

    #[test]
    fn decimal_digits_are_the_formatters_zero_padded() {
        for n in [0, 7, 10, 99, 1_000_000_000, 123_456_789_012, u64::MAX] {
            for width in [1, 2, 6, 9, 20] {
                let mut s = b"x".to_vec();
                push_decimal(&mut s, n, width);
                assert_eq!(
                    String::from_utf8_lossy(&s),
                    format!("x{n:0width$}"),
                    "{n} {width}"
                );
            }
        }
    }

    fn quat(w: f64, x: f64, y: f64, z: f64) -> UnitQuaternion<f64> {
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
    }

    fn rel_close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-6 * b.abs().max(1e-12)
    }

    /// SplitMix64: a PRNG both evo's side and ours reproduce bit for bit (the fixtures
    /// are written once from it and read back by evo).
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }

        /// Uniform in [-a, a).
        fn sym(&mut self, a: f64) -> f64 {
            ((self.next() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * a
        }
    }

    /// A random walk sampled at knots every 0.1 s from t = 1000 s, linear in between.
    /// Only + − × ÷ and sqrt (correctly rounded everywhere), so the TUM text it gives is
    /// the same on every machine.
    struct Truth {
        p: Vec<Vector3<f64>>,
        q: Vec<UnitQuaternion<f64>>,
    }

    const T0: f64 = 1000.0;
    const KNOT_DT: f64 = 0.1;

    impl Truth {
        fn new(rng: &mut Rng, knots: usize) -> Self {
            let (mut p, mut q) = (vec![Vector3::zeros()], vec![UnitQuaternion::identity()]);
            for i in 1..knots {
                let step = Vector3::new(0.03 + rng.sym(0.05), rng.sym(0.05), rng.sym(0.02));
                p.push(p[i - 1] + step);
                let dq = quat(1.0, rng.sym(0.01), rng.sym(0.01), rng.sym(0.03));
                q.push(q[i - 1] * dq);
            }
            Truth { p, q }
        }

        fn at(&self, t: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
            let x = ((t - T0) / KNOT_DT).clamp(0.0, (self.p.len() - 1) as f64);
            let i = (x as usize).min(self.p.len() - 2);
            let f = x - i as f64;
            let p = self.p[i] * (1.0 - f) + self.p[i + 1] * f;
            let q = if f < 0.5 { self.q[i] } else { self.q[i + 1] };
            (p, q)
        }
    }

    /// The known transform from the reference frame to the estimate's.
    fn est_from_ref() -> Sim3 {
        Sim3 {
            rotation: *quat(0.9, 0.1, -0.2, 0.35).to_rotation_matrix().matrix(),
            translation: Vector3::new(1.5, -2.0, 0.3),
            scale: 0.8,
        }
    }

    /// Reference sampled every `ref_dt` (jitter ±2 ms), estimate every `est_dt` (jitter
    /// ±3 ms, stamps shifted by `-est_clock_offset`), estimate = known Sim(3) of the
    /// truth plus ±2 cm noise and a small rotation error.
    fn fixture(seed: u64, ref_dt: f64, est_dt: f64, est_clock_offset: f64) -> (String, String) {
        let mut rng = Rng(seed);
        let truth = Truth::new(&mut rng, 301);
        let end = T0 + 30.0;
        let mut reference = Trajectory::new();
        let mut i = 0.0;
        while T0 + i * ref_dt < end {
            let t = T0 + i * ref_dt + rng.sym(0.002);
            let (p, q) = truth.at(t);
            reference.push(t, p, q);
            i += 1.0;
        }
        let sim = est_from_ref();
        let r =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(sim.rotation));
        let mut estimate = Trajectory::new();
        let mut j = 0.0;
        while T0 + j * est_dt < end {
            let t = T0 + j * est_dt + rng.sym(0.003);
            let (p, q) = truth.at(t);
            let noise = Vector3::new(rng.sym(0.02), rng.sym(0.02), rng.sym(0.02));
            let dq = quat(1.0, rng.sym(0.005), rng.sym(0.005), rng.sym(0.005));
            estimate.push(t - est_clock_offset, sim.apply(&p) + noise, r * q * dq);
            j += 1.0;
        }
        match (reference.to_tum(), estimate.to_tum()) {
            (Ok(a), Ok(b)) => (a, b),
            _ => panic!("ragged fixture"),
        }
    }

    /// The cross-check cases: (name, seed, ref_dt, est_dt, est clock offset).
    const CASES: [(&str, u64, f64, f64, f64); 5] = [
        // Estimate denser than the reference (evo matches from the reference).
        ("dense", 1, 0.1, 1.0 / 30.0, 0.0),
        // Estimate sparser (evo matches from the estimate: the swapped branch).
        ("sparse", 2, 0.1, 0.2, 0.0),
        // Estimate clock 0.5 s behind, undone with --t_offset 0.5.
        ("offset", 3, 0.1, 1.0 / 30.0, 0.5),
        // Incommensurate rates: most poses find no partner within 10 ms, from either side.
        ("drop_est", 4, 0.1, 1.0 / 7.0, 0.0),
        ("drop_ref", 5, 0.1, 0.075, 0.0),
    ];

    fn parsed(case: &str) -> (Trajectory, Trajectory) {
        let Some(&(_, seed, rdt, edt, off)) = CASES.iter().find(|c| c.0 == case) else {
            panic!("no case {case}")
        };
        let (r, e) = fixture(seed, rdt, edt, off);
        // Parsed back, so we compare exactly the numbers evo read from the files.
        match (
            Trajectory::parse_tum(&r, Path::new("ref.tum")),
            Trajectory::parse_tum(&e, Path::new("est.tum")),
        ) {
            (Ok(r), Ok(e)) => (r, e),
            (r, e) => panic!("{r:?} {e:?}"),
        }
    }

    /// FNV-1a, to pin the fixture text evo was given.
    fn fnv(s: &str) -> u64 {
        s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
        })
    }

    /// Writes the fixtures for `evo_ape` (see tests/py/evo_crosscheck.sh).
    #[test]
    #[ignore = "writes fixtures for the evo cross-check into $EVO_FIXTURE_DIR"]
    fn write_evo_fixtures() {
        let Some(dir) = std::env::var_os("EVO_FIXTURE_DIR") else {
            panic!("set EVO_FIXTURE_DIR")
        };
        let dir = PathBuf::from(dir);
        for (name, seed, rdt, edt, off) in CASES {
            let (r, e) = fixture(seed, rdt, edt, off);
            println!("(\"{name}\", {:#x}, {:#x}),", fnv(&r), fnv(&e));
            std::fs::write(dir.join(format!("{name}_ref.tum")), r).unwrap();
            std::fs::write(dir.join(format!("{name}_est.tum")), e).unwrap();
        }
    }

    /// `evo_ape` command-line options → ours.
    fn options(args: &str) -> ApeOptions {
        let mut o = ApeOptions::default();
        let mut it = args.split_whitespace();
        while let Some(a) = it.next() {
            let mut value = || it.next().and_then(|v| v.parse().ok()).unwrap_or(f64::NAN);
            match a {
                "-a" => o.align = true,
                "-s" => o.correct_scale = true,
                "-as" => (o.align, o.correct_scale) = (true, true),
                "--align_origin" => o.align_origin = true,
                "--t_offset" => o.offset_s = value(),
                "--t_max_diff" => o.max_diff_s = value(),
                _ => panic!("unknown option {a}"),
            }
        }
        o
    }

    /// FNV-1a of each fixture (ref, est) as written for evo: the inputs are unchanged.
    const FIXTURE_HASHES: [(&str, u64, u64); 5] = [
        ("dense", 0x78b41832dd7cfe28, 0xa8d7ae0fdf0cee8c),
        ("sparse", 0xbf4ce11a25aac6c2, 0x78851002c47056cb),
        ("offset", 0x69b32d0b5eb966d8, 0x80ed4a674b3dcf2a),
        ("drop_est", 0x4f5b76cd90106bbd, 0x77c6bc713cde42a1),
        ("drop_ref", 0xcc6c97ba0eca13dc, 0x7e2fd5f22809de8e),
    ];

    /// evo 1.38.1, `tests/py/evo_crosscheck.sh`: `evo_ape tum <case>_ref.tum <case>_est.tum
    /// <args> --save_results`: (case, args, [rmse, mean, median, std, min, max, sse], n).
    const EVO: [(&str, &str, [f64; 7], usize); 17] = [
        (
            "dense",
            "",
            [
                2.803539439082989,
                2.6139486975068356,
                2.3083280288355725,
                1.0134621814828981,
                1.4653328249344573,
                4.752742658537221,
                2357.9500159481277,
            ],
            300,
        ),
        (
            "dense",
            "-a",
            [
                0.5169209937987246,
                0.45403779713546916,
                0.4651374618440643,
                0.2470971319182633,
                0.016435976280245377,
                0.9099539263727334,
                80.16219414895832,
            ],
            300,
        ),
        (
            "dense",
            "-as",
            [
                0.025244570344932285,
                0.024105281468331866,
                0.024851722660141913,
                0.007498248944435678,
                0.0036298837482756563,
                0.04181192217796385,
                0.1911864995700704,
            ],
            300,
        ),
        (
            "dense",
            "-s",
            [
                3.2345774559043363,
                3.0937933030046776,
                2.7891243846725313,
                0.9438931700822797,
                2.007026044125573,
                5.178228807822156,
                3138.7473954733705,
            ],
            300,
        ),
        (
            "dense",
            "--align_origin",
            [
                1.037003864953051,
                0.8997802371680145,
                0.9473253657403329,
                0.5155313188637889,
                1.5396270933599815e-16,
                1.7354963221148267,
                322.61310477826976,
            ],
            300,
        ),
        (
            "sparse",
            "",
            [
                2.8785734082496752,
                2.6594790585845356,
                2.21613738436594,
                1.1015243999260582,
                1.4819318982665972,
                5.176822509947611,
                1242.9277300023225,
            ],
            150,
        ),
        (
            "sparse",
            "-a",
            [
                0.5408148819425959,
                0.4754997677334913,
                0.4975594472714473,
                0.25764453694184875,
                0.020608074366591726,
                0.9708855761579802,
                43.87211047958758,
            ],
            150,
        ),
        (
            "sparse",
            "-as",
            [
                0.0250101781383855,
                0.023975358463718458,
                0.023864357866509964,
                0.007119775070181605,
                0.002208655770110489,
                0.038945394834430394,
                0.09382635157706637,
            ],
            150,
        ),
        (
            "offset",
            "--t_offset 0.5",
            [
                3.0592863170925875,
                2.809152703766456,
                2.444791425015846,
                1.211566695180887,
                1.4588084774037096,
                5.560688205850363,
                2807.769830984978,
            ],
            300,
        ),
        (
            "offset",
            "-a --t_offset 0.5 --t_max_diff 0.02",
            [
                0.5581705976100013,
                0.4864828185054017,
                0.4754914300725575,
                0.2736583332101297,
                0.04846945831207974,
                1.006970407148662,
                93.4663248108918,
            ],
            300,
        ),
        (
            "offset",
            "-as --t_offset 0.5 --t_max_diff 0.02",
            [
                0.024494849868645252,
                0.023484920177514034,
                0.0240724952314453,
                0.006961048365243884,
                0.0029235692930590926,
                0.03848861488529413,
                0.1799993010262411,
            ],
            300,
        ),
        (
            "drop_est",
            "",
            [
                3.003925415068473,
                2.7579859891926795,
                2.459688153553809,
                1.190412190256456,
                1.4864558533531338,
                5.356238022601821,
                279.73060487812324,
            ],
            31,
        ),
        (
            "drop_ref",
            "",
            [
                2.9748217695892887,
                2.716280709119875,
                2.2920686067316964,
                1.2130060470111332,
                1.3940013587119684,
                5.259793779610051,
                884.9564560822347,
            ],
            100,
        ),
        (
            "drop_est",
            "-a",
            [
                0.5567041159422076,
                0.4809313902703323,
                0.5004433124073703,
                0.2804005537791254,
                0.059346752812227566,
                0.9555613343595015,
                9.607503653916842,
            ],
            31,
        ),
        (
            "drop_ref",
            "-a",
            [
                0.5549842741090523,
                0.48098648140288314,
                0.4792836560430798,
                0.2768746091934499,
                0.028016087085883726,
                0.9773692094290766,
                30.800754450835164,
            ],
            100,
        ),
        (
            "drop_est",
            "-as",
            [
                0.02429198200690163,
                0.023389767826420195,
                0.022620010918013966,
                0.006558898600359037,
                0.011587427068857199,
                0.036257174387007686,
                0.01829311208453261,
            ],
            31,
        ),
        (
            "drop_ref",
            "-as",
            [
                0.02414531743417461,
                0.02305478128231374,
                0.023079649569772976,
                0.007174497475205656,
                0.0012701967966132863,
                0.04023160064704285,
                0.05829963539970564,
            ],
            100,
        ),
    ];

    #[test]
    fn fixtures_are_the_files_evo_read() {
        for (case, r, e) in FIXTURE_HASHES {
            let Some(&(_, seed, rdt, edt, off)) = CASES.iter().find(|c| c.0 == case) else {
                panic!("no case {case}")
            };
            let (rt, et) = fixture(seed, rdt, edt, off);
            assert_eq!((fnv(&rt), fnv(&et)), (r, e), "{case}");
        }
    }

    #[test]
    fn matches_evo_ape() {
        for (case, args, want, n) in EVO {
            let (r, e) = parsed(case);
            let got = evo_ape(&r, &e, &options(args))
                .unwrap_or_else(|err| panic!("{case} {args}: {err}"));
            assert_eq!(got.n, n, "{case} {args}");
            let g = [
                got.rmse, got.mean, got.median, got.std, got.min, got.max, got.sse,
            ];
            for (k, (g, w)) in g.iter().zip(want).enumerate() {
                // min is ~1e-16 after origin alignment: compare it absolutely there.
                let ok = rel_close(*g, w) || (w.abs() < 1e-12 && g.abs() < 1e-12);
                assert!(ok, "{case} {args}: stat {k}: {g} vs evo {w}");
            }
        }
    }

    #[test]
    fn tum_round_trip_is_byte_stable() {
        let (r, _) = parsed("dense");
        let text = r.to_tum().unwrap_or_default();
        let again = Trajectory::parse_tum(&text, Path::new("x.tum"))
            .and_then(|t| t.to_tum())
            .unwrap_or_default();
        assert_eq!(text, again);
        let first = text.lines().next().unwrap_or_default();
        assert_eq!(first.split(' ').count(), 8);
        assert!(first.starts_with("1000."), "{first}");
    }

    #[test]
    fn tum_write_and_read_a_file() {
        let path = std::env::temp_dir().join(format!("eval-test-{}.tum", std::process::id()));
        let mut t = Trajectory::new();
        t.push(1.5, Vector3::new(1.0, -2.0, 3.25), quat(0.0, 0.0, 0.0, 1.0));
        t.push(2.0, Vector3::new(0.0, 0.0, 0.0), UnitQuaternion::identity());
        let written = t
            .write_tum(&path)
            .and_then(|()| Trajectory::read_tum(&path));
        let _ = std::fs::remove_file(&path);
        let back = written.unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back.t, t.t);
        assert_eq!(back.p, t.p);
        assert!(back.q[0].angle_to(&t.q[0]) < 1e-9);
        assert_eq!(
            t.to_tum().unwrap_or_default(),
            "1.500000 1.000000000 -2.000000000 3.250000000 0.000000000 0.000000000 1.000000000 0.000000000\n\
             2.000000 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 1.000000000\n"
        );
    }

    #[test]
    fn tum_comments_and_errors_name_the_line() {
        let ok =
            "# t x y z qx qy qz qw\n\n1 0 0 0 0 0 0 1\n  # indented comment\n2 1 0 0 0 0 0 2\n";
        let t = Trajectory::parse_tum(ok, Path::new("a.tum")).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(t.len(), 2);
        assert!(t.q[1].angle() < 1e-12); // normalized
        let cases = [
            ("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n", "a.tum:2: 7 fields"),
            ("1 0 0 0 0 0 0 1\n\n2 0 0 x 0 0 0 1\n", "a.tum:3:4: \"x\""),
            ("1 0 0 nan 0 0 0 1\n", "a.tum:1:4"),
            ("1 0 0 0 0 0 0 0\n", "a.tum:1:5: zero quaternion"),
            ("# only a comment\n", "a.tum: no poses"),
        ];
        for (text, want) in cases {
            match Trajectory::parse_tum(text, Path::new("a.tum")) {
                Err(e) => assert!(e.to_string().starts_with(want), "{e} vs {want}"),
                Ok(t) => panic!("parsed {t:?}"),
            }
        }
    }

    #[test]
    fn matching_follows_evo_rules() {
        let s2 = [1.0, 2.0, 3.0, 4.0];
        // Tie between 2.0 and 3.0 goes to the earlier; 5.02 is out of range; 4.005
        // matches past the end; two stamps may share a partner.
        let (a, b) = matching_time_indices(&[0.995, 2.5, 3.004, 3.006, 4.005, 5.02], &s2, 0.5, 0.0);
        assert_eq!(a, [0, 1, 2, 3, 4]);
        assert_eq!(b, [0, 1, 2, 2, 3]);
        // The offset shifts the second list.
        let (a, b) = matching_time_indices(&[1.5, 2.5], &s2, 0.01, 0.5);
        assert_eq!((a, b), (vec![0, 1], vec![0, 1]));
        // Unsorted: linear search, still nearest.
        let (a, b) = matching_time_indices(&[1.0, 2.999], &[3.0, 1.0, 2.0], 0.01, 0.0);
        assert_eq!((a, b), (vec![0, 1], vec![1, 0]));
        assert_eq!(
            matching_time_indices(&[1.0], &[], 0.01, 0.0),
            (vec![], vec![])
        );
    }

    #[test]
    fn associate_keeps_argument_order_and_reports_no_match() {
        let mut a = Trajectory::new();
        let mut b = Trajectory::new();
        for i in 0..10 {
            a.push(
                i as f64,
                Vector3::new(i as f64, 0.0, 0.0),
                UnitQuaternion::identity(),
            );
        }
        for i in 0..4 {
            b.push(
                2.0 * i as f64 + 0.004,
                Vector3::new(0.0, i as f64, 0.0),
                UnitQuaternion::identity(),
            );
        }
        let (ra, rb) = associate(&a, &b, 0.01, 0.0).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(ra.t, [0.0, 2.0, 4.0, 6.0]);
        assert_eq!(rb.t, [0.004, 2.004, 4.004, 6.004]);
        let (rb2, ra2) = associate(&b, &a, 0.01, 0.0).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((ra2.t, rb2.t), (ra.t.clone(), rb.t.clone()));
        assert!(matches!(
            associate(&a, &b, 0.001, 0.0),
            Err(EvalError::NoMatches { .. })
        ));
    }

    #[test]
    fn umeyama_recovers_a_known_similarity() {
        let sim = est_from_ref();
        let mut rng = Rng(7);
        let x: Vec<Vector3<f64>> = (0..50)
            .map(|_| Vector3::new(rng.sym(5.0), rng.sym(5.0), rng.sym(1.0)))
            .collect();
        let y: Vec<Vector3<f64>> = x.iter().map(|p| sim.apply(p)).collect();
        let got = umeyama(&x, &y, true).unwrap_or_else(|e| panic!("{e}"));
        assert!((got.rotation - sim.rotation).norm() < 1e-9);
        assert!((got.translation - sim.translation).norm() < 1e-9);
        assert!((got.scale - sim.scale).abs() < 1e-9);
        // Back the other way the inverse comes out.
        let inv = umeyama(&y, &x, true).unwrap_or_else(|e| panic!("{e}"));
        assert!((inv.scale * sim.scale - 1.0).abs() < 1e-9);
        // Without scale: a proper rotation all the same.
        let se3 = umeyama(&x, &y, false).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(se3.scale, 1.0);
        assert!((se3.rotation.determinant() - 1.0).abs() < 1e-9);
        // Points on a line: evo refuses, so do we.
        let line: Vec<Vector3<f64>> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert!(matches!(
            umeyama(&line, &line, false),
            Err(EvalError::Degenerate)
        ));
    }

    #[test]
    fn umeyama_never_returns_a_reflection() {
        // A mirrored point set: the best proper rotation, not the mirror.
        let x: Vec<Vector3<f64>> = [
            [1.0, 0.0, 0.0],
            [0.0, 2.0, 0.0],
            [0.0, 0.0, 3.0],
            [1.0, 1.0, 1.0],
        ]
        .iter()
        .map(|v| Vector3::from(*v))
        .collect();
        let y: Vec<Vector3<f64>> = x.iter().map(|p| Vector3::new(p.x, p.y, -p.z)).collect();
        let r = umeyama(&x, &y, false).unwrap_or_else(|e| panic!("{e}"));
        assert!((r.rotation.determinant() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn aligned_ape_of_an_exact_similarity_is_zero() {
        let (r, _) = parsed("dense");
        let sim = est_from_ref();
        let mut e = r.clone();
        e.p = r.p.iter().map(|p| sim.apply(p)).collect();
        let s = ape_translation(&r, &e, true, true).unwrap_or_else(|err| panic!("{err}"));
        assert!(s.max < 1e-9, "{s:?}");
        let s = ape_translation(&r, &e, true, false).unwrap_or_else(|err| panic!("{err}"));
        assert!(s.rmse > 0.01, "{s:?}"); // the scale is left over
        assert!(matches!(
            ape_translation(&r, &r.select(&[0, 1]), false, false),
            Err(EvalError::LengthMismatch { .. })
        ));
    }

    #[test]
    fn align_origin_moves_the_first_pose_onto_the_reference() {
        let (r, e) = parsed("dense");
        let (r, mut e) = associate(&r, &e, 0.01, 0.0).unwrap_or_else(|err| panic!("{err}"));
        e.align_origin(&r).unwrap_or_else(|err| panic!("{err}"));
        assert!((e.p[0] - r.p[0]).norm() < 1e-9);
        assert!(e.q[0].angle_to(&r.q[0]) < 1e-9);
        assert!(matches!(
            evo_ape(
                &r,
                &e,
                &ApeOptions {
                    align: true,
                    align_origin: true,
                    ..ApeOptions::default()
                }
            ),
            Err(EvalError::AlignAndOrigin)
        ));
    }

    #[test]
    fn stats_follow_numpy() {
        let s = ApeStats::from_errors(&[1.0, 2.0, 3.0, 4.0]).unwrap_or_else(|| panic!("none"));
        assert_eq!(
            (s.median, s.mean, s.min, s.max, s.sse, s.n),
            (2.5, 2.5, 1.0, 4.0, 30.0, 4)
        );
        assert!((s.std - 1.25f64.sqrt()).abs() < 1e-15);
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15);
        assert_eq!(
            ApeStats::from_errors(&[2.0, 9.0, 1.0]).map(|s| s.median),
            Some(2.0)
        );
        assert_eq!(ApeStats::from_errors(&[]), None);
    }
}
