//! The values a run saw, for the error of an empty surface ("the data range is [0, 255]").

/// Smallest and largest finite value, and how many voxels were NaN or infinite.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct DataRange {
    min: f32,
    max: f32,
    non_finite: u64,
}

impl Default for DataRange {
    fn default() -> Self {
        Self {
            min: f32::INFINITY,
            max: f32::NEG_INFINITY,
            non_finite: 0,
        }
    }
}

impl DataRange {
    pub fn add(&mut self, values: &[f32]) {
        for &v in values {
            if v.is_finite() {
                self.min = self.min.min(v);
                self.max = self.max.max(v);
            } else {
                self.non_finite += 1;
            }
        }
    }

    /// Both parts together (slabs seen by different extractors).
    pub fn merge(&mut self, o: &DataRange) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.non_finite += o.non_finite;
    }

    /// "[0, 255] (12 NaN or infinite voxels)", or what to say when no voxel was finite.
    pub fn describe(&self) -> String {
        if self.min > self.max {
            return format!(
                "the volume has no finite voxel (all {} are NaN or infinite)",
                self.non_finite
            );
        }
        let mut s = format!("the data range is [{}, {}]", self.min, self.max);
        if self.non_finite > 0 {
            s.push_str(&format!(" ({} NaN or infinite voxels)", self.non_finite));
        }
        s
    }
}
