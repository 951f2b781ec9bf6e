//! One module per subcommand (`torch`: the detector commands, handed to `pi3det-torch`).

pub mod convert;
pub mod info;
pub mod torch;
