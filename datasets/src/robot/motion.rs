//! Motion: piecewise constant-acceleration pieces of the commanded path. (Part of the robot generator; see mod.rs.)

use super::*;

// Motion: piecewise constant-acceleration pieces of the commanded path

#[derive(Debug, Clone)]
pub(super) struct Piece {
    pub(super) t0: f64,
    pub(super) t1: f64,
    pub(super) p0: V3,
    pub(super) v0: V3,
    pub(super) a: V3,
    pub(super) segment: i32,
}

impl Piece {
    pub(super) fn pos(&self, t: f64) -> V3 {
        let dt = t - self.t0;
        self.p0 + self.v0 * dt + self.a * (0.5 * dt * dt)
    }
    pub(super) fn speed(&self, t: f64) -> f64 {
        (self.v0 + self.a * (t - self.t0)).norm()
    }
}

pub(super) struct CmdPath {
    pub(super) pieces: Vec<Piece>,
    pub(super) t: f64,
    pub(super) pos: V3,
}

impl CmdPath {
    pub(super) fn line(&mut self, to: V3, speed: f64, segment: i32) {
        let d = to - self.pos;
        let len = d.norm();
        if len < 1e-12 {
            return;
        }
        let v0 = d * (speed / len);
        // A corner between two straight moves is an exact stop, as a robot
        // program without blending does: without it the commanded velocity
        // jumps (up then straight down at transit speed is 0.8 mm per 4 ms
        // cycle), beyond the replay's default envelope (0.5 mm change of
        // step per cycle, docs/replay.md).
        if let Some(last) = self.pieces.last() {
            let moving = last.a == V3::zeros() && last.v0 != V3::zeros();
            if moving && (last.v0 - v0).norm() > 1e-9 {
                self.dwell(CORNER_STOP_S);
            }
        }
        let dt = len / speed;
        self.pieces.push(Piece {
            t0: self.t,
            t1: self.t + dt,
            p0: self.pos,
            v0,
            a: V3::zeros(),
            segment,
        });
        self.t += dt;
        self.pos = to;
    }
    pub(super) fn dwell(&mut self, dt: f64) {
        self.pieces.push(Piece {
            t0: self.t,
            t1: self.t + dt,
            p0: self.pos,
            v0: V3::zeros(),
            a: V3::zeros(),
            segment: -1,
        });
        self.t += dt;
    }
}
