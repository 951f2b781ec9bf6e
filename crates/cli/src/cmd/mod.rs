//! One module per subcommand (`torch`: the detector commands, handed to `pi3det-torch`).

pub mod info;
pub mod torch;
