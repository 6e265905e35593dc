//! One measurement for the filter's update: innovation, Jacobian and noise of up to
//! three rows, held inline. A Jacobian row reads a few states (a position its three
//! position states, with the GNSS error or an odometry offset; a body velocity the
//! three velocity states), so each row keeps only its non-zero entries: the update
//! then costs O(nnz·n), and nothing is allocated per sample.

use super::ekf::{IDX_P, IDX_TERRAIN};
use nalgebra::{DVector, Matrix3, Vector3};

/// Most rows a measurement has (a 3-D position or velocity).
pub const MAX_ROWS: usize = 3;
/// Most states one Jacobian row reads (a flow velocity reads the three velocity states,
/// its source's scale, heading, delay and compensation gyro bias, the attitude's
/// heading error, and, scaled by the filter's own height, that height's two states).
const ROW_STATES: usize = 11;

/// Innovation `y = z − h(x)`, Jacobian `H` (rows × n, sparse) and noise `R`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    rows: usize,
    y: [f64; MAX_ROWS],
    r: Matrix3<f64>,
    h: [JacobianRow; MAX_ROWS],
    /// States this measurement depends on but must not correct (Schmidt's "consider"
    /// states: unobservable here, their uncertainty still counted).
    consider: StateList<MAX_CONSIDER>,
    /// States whose prior this measurement replaces once it passes its gate (see
    /// [`Self::replace`]).
    replace: StateList<MAX_ROWS>,
}

/// Most consider states one measurement has (a flow without an IMU: its scale and
/// heading errors, the attitude's heading error, the height and terrain, and its
/// compensation gyro's two bias errors).
pub const MAX_CONSIDER: usize = 8;

/// A few state indices in a fixed array (a measurement is built per sample and
/// allocates nothing).
#[derive(Debug, Clone, Copy, PartialEq)]
struct StateList<const N: usize> {
    states: [usize; N],
    len: usize,
}

impl<const N: usize> StateList<N> {
    const EMPTY: Self = Self {
        states: [0; N],
        len: 0,
    };

    /// # Panics
    /// Beyond `N` states: no measurement the estimator makes has them.
    fn push(&mut self, state: usize, what: &str) {
        assert!(self.len < N, "too many {what} states");
        self.states[self.len] = state;
        self.len += 1;
    }

    fn as_slice(&self) -> &[usize] {
        &self.states[..self.len]
    }
}

/// One row of H: its non-zero entries, by state index.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct JacobianRow {
    len: usize,
    states: [usize; ROW_STATES],
    values: [f64; ROW_STATES],
}

impl JacobianRow {
    /// (state, value) of the non-zero entries, by ascending state.
    pub(super) fn entries(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.states[..self.len]
            .iter()
            .copied()
            .zip(self.values[..self.len].iter().copied())
    }
}

impl Measurement {
    /// A measurement of `rows` rows (1 to [`MAX_ROWS`]), all zero.
    ///
    /// # Panics
    /// On 0 or more than [`MAX_ROWS`] rows: no measurement the estimator makes has them.
    pub fn new(rows: usize) -> Self {
        assert!(
            (1..=MAX_ROWS).contains(&rows),
            "a measurement has 1 to {MAX_ROWS} rows, not {rows}"
        );
        Self {
            rows,
            y: [0.0; MAX_ROWS],
            r: Matrix3::zeros(),
            h: [JacobianRow::default(); MAX_ROWS],
            consider: StateList::EMPTY,
            replace: StateList::EMPTY,
        }
    }

    /// `state`'s prior is replaced: the measurement is gated against the prior as
    /// usual, then, accepted, the state forgets what it knew (uncorrelated, a variance
    /// far beyond any innovation) and takes the measurement as its value. For a state
    /// the model predicts no better than a stand-in (a velocity with nothing driving
    /// it): the value is the measurement's, its error the measurement's and nothing
    /// of the stand-in's lag or pull is smoothed into the others.
    pub fn replace(&mut self, state: usize) {
        self.replace.push(state, "replaced");
    }

    /// The states whose prior is replaced.
    pub fn replaced(&self) -> &[usize] {
        self.replace.as_slice()
    }

    /// `state` is considered, not corrected (its Jacobian entries stay: they carry its
    /// uncertainty into the innovation's).
    pub fn consider(&mut self, state: usize) {
        self.consider.push(state, "consider");
    }

    /// The states considered, not corrected.
    pub fn considered(&self) -> &[usize] {
        self.consider.as_slice()
    }

    /// Direct measurements of the states `first..first + rows` (position, velocity):
    /// innovations `y`, noise the top-left `rows`×`rows` of `r`.
    pub fn of_states(first: usize, rows: usize, y: &Vector3<f64>, r: &Matrix3<f64>) -> Self {
        let mut m = Self::new(rows);
        for i in 0..rows {
            m.set_jacobian(i, first + i, 1.0);
            m.y[i] = y[i];
            for j in 0..rows {
                m.r[(i, j)] = r[(i, j)];
            }
        }
        m
    }

    /// The height above the terrain, `p_z − z_t`: innovation `y`, variance `var`.
    pub fn height(y: f64, var: f64) -> Self {
        let mut m = Self::new(1);
        m.set_jacobian(0, IDX_P + 2, 1.0);
        m.set_jacobian(0, IDX_TERRAIN, -1.0);
        m.y[0] = y;
        m.r[(0, 0)] = var;
        m
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    pub fn innovation(&self) -> &[f64] {
        &self.y[..self.rows]
    }

    pub fn set_innovation(&mut self, row: usize, y: f64) {
        self.y[..self.rows][row] = y;
    }

    pub fn set_noise(&mut self, row: usize, col: usize, v: f64) {
        assert!(
            row < self.rows && col < self.rows,
            "noise ({row}, {col}) outside"
        );
        self.r[(row, col)] = v;
    }

    pub(super) fn noise(&self, row: usize, col: usize) -> f64 {
        self.r[(row, col)]
    }

    /// H[row, state] = `value`. A zero is not kept (H·P skips it, as the dense product
    /// would multiply by it for nothing).
    ///
    /// # Panics
    /// When the row already reads [`ROW_STATES`] other states.
    pub fn set_jacobian(&mut self, row: usize, state: usize, value: f64) {
        let r = &mut self.h[..self.rows][row];
        let at = r.states[..r.len].partition_point(|&s| s < state);
        if at < r.len && r.states[at] == state {
            if value == 0.0 {
                r.states.copy_within(at + 1..r.len, at);
                r.values.copy_within(at + 1..r.len, at);
                r.len -= 1;
            } else {
                r.values[at] = value;
            }
            return;
        }
        if value == 0.0 {
            return;
        }
        assert!(
            r.len < ROW_STATES,
            "a Jacobian row reads at most {ROW_STATES} states"
        );
        r.states.copy_within(at..r.len, at + 1);
        r.values.copy_within(at..r.len, at + 1);
        r.states[at] = state;
        r.values[at] = value;
        r.len += 1;
    }

    pub(super) fn jacobian_row(&self, row: usize) -> &JacobianRow {
        &self.h[..self.rows][row]
    }

    /// The same measurement linearised about the state `to` instead of `from` (to
    /// first order: `y − H (to − from)`), for another filter of the same layout.
    pub fn about(&self, from: &DVector<f64>, to: &DVector<f64>) -> Self {
        let mut m = *self;
        for (row, y) in self.h[..self.rows].iter().zip(&mut m.y) {
            for (k, hk) in row.entries() {
                *y -= hk * (to[k] - from[k]);
            }
        }
        m
    }

    /// The largest state index H reads, if any.
    pub(super) fn max_state(&self) -> Option<usize> {
        self.h[..self.rows]
            .iter()
            .filter_map(|r| r.states[..r.len].last().copied())
            .max()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobian_rows_keep_their_non_zero_entries_by_state() {
        let mut m = Measurement::new(2);
        m.set_jacobian(1, 9, -1.0);
        m.set_jacobian(1, 2, 1.0);
        m.set_jacobian(1, 16, 0.5);
        m.set_jacobian(1, 5, 0.0);
        let row: Vec<_> = m.jacobian_row(1).entries().collect();
        assert_eq!(row, [(2, 1.0), (9, -1.0), (16, 0.5)]);
        m.set_jacobian(1, 9, 0.0);
        m.set_jacobian(1, 2, 3.0);
        let row: Vec<_> = m.jacobian_row(1).entries().collect();
        assert_eq!(row, [(2, 3.0), (16, 0.5)]);
        assert_eq!(m.jacobian_row(0).entries().count(), 0);
        assert_eq!(m.max_state(), Some(16));
    }

    #[test]
    #[should_panic(expected = "at most")]
    fn a_row_reading_too_many_states_is_a_bug_caught_at_once() {
        let mut m = Measurement::new(1);
        for s in 0..=ROW_STATES {
            m.set_jacobian(0, s, 1.0);
        }
    }
}
