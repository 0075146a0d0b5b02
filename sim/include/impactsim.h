#pragma once
namespace impactsim {
int version();
}
