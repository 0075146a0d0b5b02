// Table-driven random forests (emlearn style): a model is data, walked by one small function.
//
// Node layout (7 bytes a node, in four parallel arrays so each stays naturally aligned):
//   feature u8   feature index, kLeaf for a leaf
//   value f32    split threshold (go left when x[feature] <= value), or the leaf value
//   right u16    index of the right child inside the tree; the left child is always the next node
//                (scikit-learn builds trees depth-first, the exporter checks it)
// Regressors: leaf value = the tree's prediction; the forest averages them.
// Binary classifiers: leaf value = P(class 1); class 1 when the forest's mean exceeds 0.5 (argmax with
// ties to class 0, as scikit-learn's soft vote).
// Thresholds are scikit-learn's float64 split points rounded DOWN to float32, so `x <= t` on float32
// inputs decides exactly as scikit-learn's comparison of the float32-cast input with the float64 split.
#pragma once

#include <stdint.h>

namespace impactapp {

constexpr uint8_t kLeaf = 0xFF;

struct ForestTables {
  int32_t n_trees;
  const int32_t* roots;     // [n_trees] first node of each tree in the arrays below
  const uint8_t* feature;   // [n_nodes]
  const float* value;       // [n_nodes]
  const uint16_t* right;    // [n_nodes]
};

// Mean of the trees' leaf values for feature vector x.
float forest_mean(const ForestTables& f, const float* x);

// A linear model in the same arrays (host height_class.linear_tables; the energy class of a model whose card
// chose the linear estimate of log m g h): n_trees terms; term t's factors are feature[roots[t] ..
// roots[t] + 2] (input positions, kLeaf: none); value = [coef (n_trees), bias, offset_0, scale_0, offset_1,
// scale_1, ...]. Returns 0.5 + bias + sum_t coef_t * prod((x[f] - offset_f) * scale_f), so that > 0.5 is
// class 1 as for a classifier forest; right is unused.
float linear_terms(const ForestTables& f, const float* x);

}  // namespace impactapp
