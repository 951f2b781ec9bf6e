//! Sequences → the released Pi3DET layout (`training/point_cloud/<id>.bin` + `pi3det_infos_<split>.pkl`
//! with poses, sequence names and timestamps), so every pi3det command runs on them.
