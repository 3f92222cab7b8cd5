// Placeholder until the DiLiGenT importer lands.
